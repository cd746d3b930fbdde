"""Episode k of a campaign: a scenario drawn as a pure function of (campaign seed, k).

:func:`draw_episode` seeds ``numpy.random.Generator(PCG64(SeedSequence([seed, k])))``
and draws, in this order: the simulator's seed, the base scenario (by weight), the
parking offset, the noise scale, the layout (clutter, blockers, movers; a layout that
breaks a rule is redrawn whole) and the faults. Positions are rounded to the millimetre
and angles to the micro-degree, so that an exported scenario file reads back as the very
same scenario (:func:`export_scenario`).

Placement rules (:mod:`executive.campaign.route`; the comments of
missions/a320/scenarios/busy-apron.xml and ``make_layout`` of
benchmarks/bench_avoidance_campaign.py): nothing drawn enters a forbidden zone, the
aircraft footprint at the true parking pose, the discs the robot turns in at its start
and at the station, or a base scenario obstacle (nor another drawn obstacle); clutter
keeps ``clearance`` from every leg; blockers stand on a leg, ``end-margin`` from every
route point, leaving a ``gap`` wide passage; a crossing walks across a leg at right angles
from and to points ``clearance`` or more from every leg, its sweep touching no static
obstacle; a chaser waits ``clearance`` or more from every leg.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypeVar

import numpy as np
from shapely.geometry import LineString, Point
from shapely.geometry.base import BaseGeometry

from executive.campaign.route import (
    Leg,
    RouteMap,
    obstacle_geometry,
    passable,
    sweep_geometry,
)
from executive.campaign.spec import (
    BlockerDist,
    Campaign,
    ClutterDist,
    MoverDist,
    StaticShape,
)
from executive.core.files import write_atomic
from executive.core.frames import Pose2
from sim2d.scenario import (
    Body,
    Chaser,
    Fault,
    NoiseLevels,
    Obstacle,
    ObstacleKind,
    PathMover,
    Scenario,
    StaticObstacle,
    default_library_root,
    scenario_xml,
)

MAX_DRAWS = 50
"""Layouts tried before an episode is declared impossible (a campaign that asks for
more obstacles than its apron can hold)."""
ITEM_DRAWS = 200
"""Places tried for one obstacle before its layout is redrawn."""
OFFSET_DRAWS = 100
"""Parking offsets tried before giving up (the base obstacles or the robot's start
inside the aircraft footprint at the drawn pose)."""
OBSTACLE_GAP = 0.3
"""Metres kept between two drawn obstacles (and from a base obstacle)."""
NOISE_LIMITS = NoiseLevels(
    laser_range=1.0, pixel=20.0, camera_dropout=1.0, wheel=1.0, imu_rate=1.0, imu_bias=1.0, gps=10.0
)
"""The scenario format's upper bounds (schemas/scenario.xsd): a scaled level is capped."""


T = TypeVar("T")


class SamplingError(RuntimeError):
    """No layout obeying the rules was found for an episode."""


@dataclass(frozen=True)
class Episode:
    """One drawn episode: its scenario and what was drawn, for the results."""

    index: int
    campaign_seed: int
    base: str
    """The base scenario's id."""
    scenario: Scenario
    params: dict[str, object] = field(default_factory=dict)


def episode_rng(seed: int, index: int) -> np.random.Generator:
    """The generator of episode ``index``: a pure function of (seed, index)."""
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence([seed, index])))


def episode_scenario(campaign: Campaign, index: int) -> Scenario:
    """Episode ``index``'s scenario."""
    return draw_episode(campaign, index).scenario


def _mm(x: float) -> float:
    return round(float(x), 3)


def _weighted(rng: np.random.Generator, weights: list[float]) -> int:
    p = np.asarray(weights, dtype=float)
    return int(rng.choice(len(p), p=p / p.sum()))


def _deg_pose(x: float, y: float, heading_deg: float) -> Pose2:
    return Pose2(_mm(x), _mm(y), math.radians(round(heading_deg, 6)))


def draw_episode(campaign: Campaign, index: int) -> Episode:
    """Episode ``index`` of ``campaign`` (module docstring); raises SamplingError when no
    layout obeys the rules after :data:`MAX_DRAWS` draws."""
    rng = episode_rng(campaign.seed, index)
    sim_seed = int(rng.integers(0, 2**32))
    base = campaign.scenarios[_weighted(rng, [b.weight for b in campaign.scenarios])].scenario
    scenario = dataclasses.replace(
        base,
        id=f"{base.id}.{campaign.id}.{index}",
        seed=sim_seed,
        duration=campaign.duration if campaign.duration is not None else base.duration,
        description=f"Episode {index} of campaign '{campaign.id}' (seed {campaign.seed}) "
        f"on scenario '{base.id}'.",
    )
    params: dict[str, object] = {}
    if campaign.parking_offset is not None:
        scenario = _draw_offset(rng, campaign, scenario)
    off = scenario.parking_offset
    params["parking_offset"] = {
        "dx": off.x,
        "dy": off.y,
        "dheading_deg": round(math.degrees(off.theta), 6),
    }
    scale = 1.0
    if campaign.noise_scale is not None:
        scale = round(campaign.noise_scale.draw(rng), 4)
        scenario = dataclasses.replace(scenario, noise=_scaled_noise(base.noise, scale))
    params["noise_scale"] = scale
    drawn, layout = _draw_layout(rng, campaign, scenario, index)
    faults = _draw_faults(rng, campaign)
    scenario = dataclasses.replace(
        scenario, obstacles=base.obstacles + tuple(drawn), faults=base.faults + faults
    )
    params |= layout
    params["faults"] = [f"{f.kind}" + (f" {f.target}" if f.target else "") for f in faults]
    return Episode(index, campaign.seed, base.id, scenario, params)


def _draw_offset(rng: np.random.Generator, campaign: Campaign, scenario: Scenario) -> Scenario:
    dist = campaign.parking_offset
    assert dist is not None
    for _ in range(OFFSET_DRAWS):
        dx, dy, dh = dist.dx.draw(rng), dist.dy.draw(rng), dist.dheading_deg.draw(rng)
        candidate = dataclasses.replace(scenario, parking_offset=_deg_pose(dx, dy, dh))
        if _parking_ok(candidate):
            return candidate
    raise SamplingError(
        f"campaign '{campaign.id}': no parking offset keeps scenario '{scenario.id}' valid "
        f"(its obstacles or the robot's start inside the aircraft) after {OFFSET_DRAWS} draws"
    )


def _parking_ok(scenario: Scenario) -> bool:
    """The loader's rule: no static obstacle, nor the robot at its start or at the
    station, inside the aircraft footprint at the true parking pose."""
    route = RouteMap(dataclasses.replace(scenario, obstacles=()))
    platform = scenario.mission.platform
    robot = Body(length=platform.length, width=platform.width)
    station = scenario.mission.airport.station
    for pose in (scenario.start, station):
        if route.footprint.intersects(obstacle_geometry(_static("robot", pose, robot))):
            return False
    statics = [o for o in scenario.obstacles if isinstance(o, StaticObstacle)]
    return not any(route.footprint.intersects(obstacle_geometry(o)) for o in statics)


def _static(oid: str, pose: Pose2, body: Body, height: float = 1.0) -> StaticObstacle:
    return StaticObstacle(oid, ObstacleKind.OTHER, pose, body, height)


def _scaled_noise(noise: NoiseLevels, scale: float) -> NoiseLevels:
    values = {
        f.name: min(getattr(noise, f.name) * scale, getattr(NOISE_LIMITS, f.name))
        for f in dataclasses.fields(NoiseLevels)
    }
    return NoiseLevels(**values)


# -- layouts -----------------------------------------------------------------------------------
def _shape_obstacle(
    rng: np.random.Generator, shape: StaticShape, oid: str, x: float, y: float
) -> StaticObstacle:
    """A static obstacle of ``shape`` (drawn size, any heading) centred at (x, y)."""
    if shape.radius is not None:
        body = Body(radius=_mm(shape.radius.draw(rng)))
        pose = Pose2(_mm(x), _mm(y), 0.0)
    else:
        assert shape.length is not None and shape.width is not None
        body = Body(length=_mm(shape.length.draw(rng)), width=_mm(shape.width.draw(rng)))
        pose = _deg_pose(x, y, float(rng.uniform(0.0, 180.0)))
    return StaticObstacle(oid, shape.kind, pose, body, shape.height)


def _pick_leg(rng: np.random.Generator, legs: list[Leg]) -> Leg | None:
    """A leg drawn with probability proportional to its length."""
    if not legs:
        return None
    return legs[_weighted(rng, [leg.length for leg in legs])]


def _clear_of(geom: BaseGeometry, placed: list[BaseGeometry]) -> bool:
    return all(geom.distance(other) >= OBSTACLE_GAP for other in placed)


def _retry(draw: Callable[[], T | None]) -> T | None:
    """``draw()`` until it gives something, at most :data:`ITEM_DRAWS` times."""
    for _ in range(ITEM_DRAWS):
        item = draw()
        if item is not None:
            return item
    return None


def _draw_clutter(
    rng: np.random.Generator,
    dist: ClutterDist,
    count: int,
    route: RouteMap,
    placed: list[BaseGeometry],
) -> list[StaticObstacle] | None:
    """``count`` obstacles off the route, each redrawn until it obeys the rules."""
    x0, y0, x1, y1 = route.bounds

    def one(oid: str) -> tuple[StaticObstacle, BaseGeometry] | None:
        shape = dist.shapes[_weighted(rng, [s.weight for s in dist.shapes])]
        x = rng.uniform(x0 - dist.spread, x1 + dist.spread)
        y = rng.uniform(y0 - dist.spread, y1 + dist.spread)
        ob = _shape_obstacle(rng, shape, oid, x, y)
        geom = obstacle_geometry(ob)
        if route.route_distance(geom) < dist.clearance or route.forbidden(geom):
            return None
        return (ob, geom) if _clear_of(geom, placed) else None

    out: list[StaticObstacle] = []
    for i in range(count):
        drawn = _retry(lambda i=i: one(f"clutter-{i + 1}"))
        if drawn is None:
            return None
        out.append(drawn[0])
        placed.append(drawn[1])
    return out


def _draw_blockers(
    rng: np.random.Generator,
    dist: BlockerDist,
    count: int,
    route: RouteMap,
    placed: list[BaseGeometry],
) -> list[StaticObstacle] | None:
    """``count`` obstacles on the legs, each redrawn until it obeys the rules; None when
    they leave no passage (the caller redraws them all)."""
    legs = [
        leg
        for leg in route.true_legs
        if leg.length >= max(dist.min_leg, 2.0 * dist.end_margin + 1e-3)
    ]
    if count and not legs:
        return None

    def one(oid: str, taken: list[BaseGeometry]) -> tuple[StaticObstacle, BaseGeometry] | None:
        leg = _pick_leg(rng, legs)
        assert leg is not None
        shape = dist.shapes[_weighted(rng, [s.weight for s in dist.shapes])]
        s = rng.uniform(dist.end_margin, leg.length - dist.end_margin)
        x, y = leg.at(s, rng.uniform(-dist.lateral, dist.lateral))
        ob = _shape_obstacle(rng, shape, oid, x, y)
        geom = obstacle_geometry(ob)
        if route.point_distance(geom) < dist.end_margin or route.forbidden(geom):
            return None
        return (ob, geom) if _clear_of(geom, taken) else None

    out: list[StaticObstacle] = []
    geoms: list[BaseGeometry] = []
    for i in range(count):
        drawn = _retry(lambda i=i: one(f"blocker-{i + 1}", placed + geoms))
        if drawn is None:
            return None
        out.append(drawn[0])
        geoms.append(drawn[1])
    for leg in route.legs:
        near = [g for g in geoms if _lane(leg, dist.corridor).intersects(g)]
        if near and not passable(leg, near, dist.corridor, dist.gap):
            return None
    placed += geoms
    return out


def _lane(leg: Leg, corridor: float) -> BaseGeometry:
    return LineString([leg.a, leg.b]).buffer(corridor, cap_style="square")


def _draw_movers(
    rng: np.random.Generator,
    dist: MoverDist,
    count: int,
    route: RouteMap,
    placed: list[BaseGeometry],
    cruise: float,
) -> list[Obstacle] | None:
    """``count`` crossings or chasers, each redrawn until it obeys the rules."""
    legs = [leg for leg in route.true_legs if leg.length >= max(dist.min_leg, 1e-3)]
    if count and not legs:
        return None
    starts: list[BaseGeometry] = []

    def one(i: int) -> Obstacle | None:
        leg = _pick_leg(rng, legs)
        assert leg is not None
        shape = dist.shapes[_weighted(rng, [s.weight for s in dist.shapes])]
        speed = round(dist.speed.draw(rng), 3)
        side = 1.0 if rng.random() < 0.5 else -1.0
        s = rng.uniform(0.25 * leg.length, 0.75 * leg.length)
        chasers = dist.chasers
        if chasers is not None and rng.random() < chasers.share:
            x, y = leg.at(s, side * chasers.offset.draw(rng))
            pursuit = chasers.pursuit
            mover: Obstacle = Chaser(
                id=f"chaser-{i + 1}",
                kind=shape.kind,
                start=(_mm(x), _mm(y)),
                body=shape.body,
                height=shape.height,
                speed=speed,
                trigger_radius=_mm(chasers.trigger.draw(rng)),
                pursuit=_mm(pursuit.draw(rng)) if pursuit is not None else None,
            )
            sweep = obstacle_geometry(mover)
            ends = [Point(mover.start)]
        else:
            h0, h1 = dist.half_length.draw(rng), dist.half_length.draw(rng)
            w0, w1 = leg.at(s, side * h0), leg.at(s, -side * h1)
            jitter = rng.uniform(-dist.timing, dist.timing)
            # the robot (at the cruise speed) is s_before short of the crossing when the
            # mover starts, so that it reaches the leg `jitter` seconds after the mover
            s_before = max(cruise * (h0 / speed + jitter), 0.0)
            trigger = min(max(math.hypot(s_before, h0), 0.1), 1000.0)
            mover = PathMover(
                id=f"mover-{i + 1}",
                kind=shape.kind,
                body=shape.body,
                height=shape.height,
                speed=speed,
                waypoints=((_mm(w0[0]), _mm(w0[1])), (_mm(w1[0]), _mm(w1[1]))),
                trigger_radius=_mm(trigger),
            )
            sweep = sweep_geometry(mover)
            ends = [Point(p) for p in mover.waypoints]
        if any(route.route_distance(p) < dist.clearance for p in ends):
            return None
        if route.forbidden(sweep) or not _clear_of(sweep, placed):
            return None
        return mover if _clear_of(obstacle_geometry(mover), starts) else None

    out: list[Obstacle] = []
    for i in range(count):
        mover = _retry(lambda i=i: one(i))
        if mover is None:
            return None
        out.append(mover)
        starts.append(obstacle_geometry(mover))
    return out


def _draw_layout(
    rng: np.random.Generator, campaign: Campaign, scenario: Scenario, index: int
) -> tuple[list[Obstacle], dict[str, object]]:
    """Clutter, blockers and movers. The counts are drawn once (so that they keep their
    distribution); each obstacle is redrawn until it obeys the rules, and the whole
    layout when blockers leave no passage."""
    route = RouteMap(scenario)
    cruise = scenario.mission.navigation.cruise_speed
    n_clutter = campaign.clutter.count.draw(rng) if campaign.clutter is not None else 0
    n_blockers = campaign.blockers.count.draw(rng) if campaign.blockers is not None else 0
    n_movers = campaign.movers.count.draw(rng) if campaign.movers is not None else 0
    for attempt in range(MAX_DRAWS):
        placed: list[BaseGeometry] = []
        clutter = (
            _draw_clutter(rng, campaign.clutter, n_clutter, route, placed)
            if campaign.clutter is not None
            else []
        )
        blockers = (
            _draw_blockers(rng, campaign.blockers, n_blockers, route, placed)
            if campaign.blockers is not None and clutter is not None
            else []
        )
        movers = (
            _draw_movers(rng, campaign.movers, n_movers, route, placed, cruise)
            if campaign.movers is not None and clutter is not None and blockers is not None
            else []
        )
        if clutter is None or blockers is None or movers is None:
            continue
        speeds = [m.speed for m in movers if isinstance(m, PathMover | Chaser)]
        return [*clutter, *blockers, *movers], {
            "movers": len(movers),
            "chasers": sum(isinstance(m, Chaser) for m in movers),
            "mover_max_speed": max(speeds, default=0.0),
            "clutter": len(clutter),
            "blockers": len(blockers),
            "redraws": attempt,
        }
    raise SamplingError(
        f"campaign '{campaign.id}', episode {index}: no layout obeys the placement rules "
        f"after {MAX_DRAWS} draws (too many obstacles for the apron, or clearances too large)"
    )


def _draw_faults(rng: np.random.Generator, campaign: Campaign) -> tuple[Fault, ...]:
    faults = []
    for dist in campaign.faults:
        happens = rng.random() < dist.probability
        at, duration = round(dist.at.draw(rng), 3), round(dist.duration.draw(rng), 3)
        factor = round(dist.factor.draw(rng), 3) if dist.factor is not None else 1.0
        if happens:
            faults.append(Fault(dist.kind, at, max(duration, 0.001), dist.target, factor))
    return tuple(faults)


# -- export ------------------------------------------------------------------------------------
class ExportError(ValueError):
    """The scenario cannot be written where asked (its mission would be out of reach)."""


def export_scenario(scenario: Scenario, path: Path | str) -> Path:
    """Write ``scenario`` as a scenario file at ``path`` that ``walkaround dry-run MISSION
    --scenario PATH`` runs identically. The file names its mission by a path relative to
    itself, which must stay inside the mission library the scenario loader allows (the
    file's great-grandparent, e.g. ``missions/`` for ``missions/a320/scenarios/x.xml``)."""
    path = Path(path)
    mission = Path(scenario.mission.source).resolve()
    folder = path.absolute().parent.resolve()
    library = default_library_root(folder / path.name)
    if not mission.is_relative_to(library):
        raise ExportError(
            f"{path}: a scenario file reaches its mission only inside its mission library "
            f"'{library}', and mission '{scenario.mission.id}' ({mission}) is outside it; "
            f"write it beside the mission's scenarios (e.g. {mission.parent / 'scenarios'})"
        )
    ref = Path(os.path.relpath(mission, folder)).as_posix()
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(path, scenario_xml(scenario, ref).encode("utf-8"))
    return path
