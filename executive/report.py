"""The dry-run report folder (ARCHITECTURE.md §9).

* ``metrics.json`` — outcome and reason; per checkpoint: reached, position and heading
  error against ground truth, time, items inspected; collisions, minimum clearance,
  e-stops, geofence breaches; tick timing; compile warnings;
  ``figures`` lists the pictures written beside it.
* ``events.jsonl`` — every controller switch with its reason, safety events, faults.
* ``trajectory.png`` — top view: aircraft, zones, obstacles, the true path coloured by the
  active controller and the estimated one, checkpoints with their achieved error,
  breaches, collisions, e-stops; a legend beside the plot names every kind of mark drawn
  and only those, and the labels are placed so that none overlaps another
  (:mod:`sim2d.labels`).
* ``timeline.png`` — controller, v, omega and the closest obstacle against r_ES and
  r_OA-trigger over time.
* ``avoidance.png`` — the avoidance episodes; only when the run avoided something.
"""

from __future__ import annotations

import io
import json
import math
import warnings
from dataclasses import asdict
from pathlib import Path
from typing import BinaryIO

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.figure import Figure

from executive.core.files import write_atomic
from executive.dryrun import TRUTH_RATE_HZ, AvoidanceSample, DryRun, Sample
from sim2d.labels import Label, fit_height, kinds_legend, place_labels, tag_all
from sim2d.view import draw_world

PALETTE = plt.get_cmap("tab10")
STOP_KINDS = ("estop-latched", "stale-sensor", "fault-stop", "geofence-stop")
"""Safety events that stop the robot, listed with their reasons in metrics.json."""


def metrics(run: DryRun) -> dict[str, object]:
    """The run's figures as a JSON-ready dict."""
    result = run.result
    truth = run.robot.truth
    clearances = [s.clearance for s in run.samples if math.isfinite(s.clearance)]
    estops = [
        e for e in result.events if e.kind == "safety" and e.detail.get("kind") == "estop-latched"
    ]
    reached = [c for c in run.checkpoints if c.reached and c.position_error is not None]
    simulated = run.robot.time
    return {
        "mission": run.scenario.mission.id,
        "scenario": run.scenario.id,
        "seed": run.scenario.seed,
        "outcome": result.outcome,
        "succeeded": run.succeeded,
        "reason": result.reason,
        "traceback": result.traceback,
        "simulated_s": round(simulated, 2),
        "wall_s": round(run.wall_time, 2),
        "speed_up": round(simulated / run.wall_time, 1) if run.wall_time > 0 else None,
        "checkpoints": [asdict(c) for c in run.checkpoints],
        "checkpoints_reached": sum(c.reached for c in run.checkpoints),
        "checkpoints_total": len(run.checkpoints),
        "max_position_error": max((c.position_error for c in reached), default=None),
        "max_heading_error_deg": max((c.heading_error_deg for c in reached), default=None),
        "items_inspected": len(result.progress.results),
        "items_detected": sum(r.detected for r in result.progress.results),
        "collisions": [
            {
                "t": round(c.time, 2),
                "with": c.other,
                "at": [round(c.x, 2), round(c.y, 2)],
                "robot_speed": round(c.robot_speed, 3),
                "robot_moving": c.robot_moving,
                "robot_closing": (
                    round(c.robot_closing, 3) if math.isfinite(c.robot_closing) else None
                ),
            }
            for c in truth.collisions
        ],
        "min_clearance": round(min(clearances), 3) if clearances else None,
        "estops": len(estops),
        "safety_stops": [
            {"t": round(e.t, 2), "kind": e.detail.get("kind"), "reason": e.detail.get("reason")}
            for e in result.events
            if e.kind == "safety" and e.detail.get("kind") in STOP_KINDS
        ],
        "geofence_breaches": [{"t": round(t, 2), "zone": z} for t, z in run.breaches],
        "localisation": localisation_metrics(run),
        "obstacle_tracking": tracking_metrics(run),
        "avoidance": avoidance_metrics(run),
        "tick_timing": result.stats.summary(),
        "warnings": run.warnings,
        "resumed_after": list(run.resumed_from),
        "feature_loss_s": run.feature_loss_s,
        "servo": run.servo,
        "stale_sensors": {
            sensor: [
                {
                    "since": i.since,
                    "detected": round(i.detected, 3),
                    "until": i.until,
                    "reason": i.reason,
                }
                for i in intervals
            ]
            for sensor, intervals in run.stale_sensors.items()
            if intervals
        },
        "causes": [{"t": round(c.t, 2), "cause": c.text} for c in run.causes],
        "first_cause": run.first_cause,
        "last_commands": [
            {"t": round(t, 3), "v": c.v, "omega": c.omega} for t, c in run.last_commands
        ],
        "journal_error": run.journal_error,
    }


def _stats(values: list[float], digits: int = 4) -> dict[str, object]:
    """n, mean, p95 and max of the finite values (None when there are none)."""
    v = np.array([x for x in values if x is not None and math.isfinite(x)], dtype=float)
    if not len(v):
        return {"n": 0, "mean": None, "p95": None, "max": None}
    return {
        "n": len(v),
        "mean": round(float(v.mean()), digits),
        "p95": round(float(np.percentile(v, 95)), digits),
        "max": round(float(v.max()), digits),
    }


def localisation_metrics(run: DryRun) -> dict[str, object]:
    """Laser registration and the pose in F against the ground truth."""
    regs = run.registrations
    by_method = {
        m: {
            "attempts": sum(r.method == m for r in regs),
            "accepted": sum(r.method == m and r.accepted for r in regs),
        }
        for m in ("global", "icp")
    }
    accepted = [r for r in regs if r.accepted]
    loc = run.localisation
    period = 1.0 / TRUTH_RATE_HZ
    time_by_reference: dict[str, float] = {}
    for s in loc:
        time_by_reference[s.reference] = time_by_reference.get(s.reference, 0.0) + period
    registered = [s for s in loc if s.reference == "aircraft"]
    last = loc[-1] if loc else None
    return {
        "registrations": by_method,
        "registration_position_error_m": _stats([r.position_error for r in accepted]),
        "registration_heading_error_deg": _stats([r.heading_error_deg for r in accepted], 3),
        "pose_f_position_error_m": _stats([s.position_error for s in loc]),
        "pose_f_position_error_registered_m": _stats([s.position_error for s in registered]),
        "pose_f_heading_error_deg": _stats([s.heading_error_deg for s in loc], 3),
        "placement_error_final": None
        if last is None
        else {"position_m": last.placement_error, "heading_deg": last.placement_heading_error_deg},
        "time_by_reference_s": {k: round(v, 1) for k, v in time_by_reference.items()},
    }


TRACK_SETTLED_AGE = 1.0
"""Tracking errors are measured on tracks at least this old (s): a new track's velocity
is still converging."""


def tracking_metrics(run: DryRun) -> dict[str, object]:
    """Tracked obstacles against the movers' ground truth."""
    tracks = run.tracks
    matched = [s for s in tracks if s.mover is not None and s.age >= TRACK_SETTLED_AGE]
    return {
        "tracks": len({s.id for s in tracks}),
        "movers_tracked": sorted({s.mover for s in matched if s.mover is not None}),
        "matched_samples": len(matched),
        "position_error_m": _stats([s.position_error for s in matched]),
        "velocity_error_mps": _stats([s.velocity_error for s in matched]),
        "on_path_samples": sum(s.danger >= 2 for s in tracks),
    }


AVOIDANCE_CONTROLLERS = ("spiral", "velocity obstacles", "fallback planner")


def avoidance_metrics(run: DryRun) -> dict[str, object]:
    """Obstacle avoidance: engagements, switches by mode and reason, clearance while
    avoiding (the true distance from the footprint to the nearest shape)."""
    switches = [e for e in run.result.events if e.kind == "controller"]
    engaged = [
        e
        for e in switches
        if str(e.detail.get("to", "")).startswith(AVOIDANCE_CONTROLLERS)
        and not str(e.detail.get("from", "")).startswith(AVOIDANCE_CONTROLLERS)
    ]
    by_mode: dict[str, int] = {}
    for e in switches:
        to = str(e.detail.get("to", ""))
        if to.startswith(AVOIDANCE_CONTROLLERS):
            kind = controller_kind(to)
            by_mode[kind] = by_mode.get(kind, 0) + 1
    samples = run.avoidance
    clearances = [a.clearance for a in samples if math.isfinite(a.clearance)]
    return {
        "engagements": len(engaged),
        "episodes": len({a.episode for a in samples}),
        "switches_to": by_mode,
        "time_s": round(len(samples) / TRUTH_RATE_HZ, 1),
        "min_clearance": round(min(clearances), 3) if clearances else None,
    }


def write_report(run: DryRun, out: Path) -> Path:
    """Write the report folder; returns its path.

    ``metrics.json`` is written last and lists under ``figures`` the pictures written
    (``avoidance.png`` only when the run avoided something): it names no missing file,
    even when writing a picture failed (that error is raised after it).
    Every file is written whole or not at all (:func:`~executive.core.files.write_atomic`:
    a temporary file renamed over the target, never through a symbolic link). An
    :class:`OSError` (a full disk) names the file it was writing.
    """
    figures: dict[str, bytes] = {}
    for name, draw in (
        ("trajectory.png", trajectory),
        ("timeline.png", timeline),
        ("avoidance.png", avoidance_plot),
    ):
        image = io.BytesIO()
        with warnings.catch_warnings():  # layout hints of a sparse plot are not the user's
            warnings.filterwarnings("ignore", category=UserWarning, module="matplotlib")
            drawn = draw(run, image)
        if drawn:
            figures[name] = image.getvalue()
    out.mkdir(parents=True, exist_ok=True)
    write_atomic(
        out / "events.jsonl",
        "".join(
            json.dumps(e.as_dict(), separators=(",", ":")) + "\n" for e in run.result.events
        ).encode(),
    )
    written: list[str] = []
    failure: OSError | None = None
    for name, png in figures.items():
        try:
            write_atomic(out / name, png)
        except OSError as exc:  # metrics.json is still written, naming what is there
            failure = failure or exc
        else:
            written.append(name)
    report = metrics(run) | {"figures": written}  # only the pictures in the folder
    write_atomic(out / "metrics.json", (json.dumps(report, indent=2) + "\n").encode())
    if failure is not None:
        raise failure
    return out


KINDS = (
    ("go to", "go to goal"),
    ("inspect", "inspection"),
    ("dwell", "dwell"),
    ("correct", "correct camera angle"),
    ("emergency", "emergency stop"),
    ("stop", "stop"),
    ("operator", "operator control"),
    ("joystick", "operator joystick"),
    ("follow operator", "follow operator"),
    ("hold: operator lost", "operator lost (asking)"),
    ("hold: relocalise", "relocalise (registration)"),
    ("spiral", "spiral avoidance"),
    ("velocity obstacles", "velocity obstacles"),
    ("fallback planner", "fallback planner"),
)


def controller_kind(name: str) -> str:
    """'go to CP07' -> 'go to goal': the controller, without the goal it works on."""
    return next((kind for prefix, kind in KINDS if name.startswith(prefix)), name)


def _controller_colours(run: DryRun) -> dict[str, object]:
    order = [kind for _, kind in KINDS]
    names = sorted(
        {controller_kind(s.controller) for s in run.samples},
        key=lambda k: order.index(k) if k in order else len(order),
    )
    return {name: PALETTE(i % 10) for i, name in enumerate(names)}


def trajectory(run: DryRun, path: Path | BinaryIO) -> bool:
    """Write :func:`trajectory_figure` as a PNG."""
    fig = trajectory_figure(run)
    fig.savefig(path, format="png")
    plt.close(fig)
    return True


def _nearest_sample(samples: list[Sample], t: float) -> Sample | None:
    """The sample nearest the time ``t`` (None for a run without samples)."""
    return min(samples, key=lambda s: abs(s.t - t)) if samples else None


def trajectory_figure(run: DryRun) -> Figure:
    """The run seen from above: the world (no scan, no camera), the true path coloured by
    the active controller, the estimated path, tracked movers, registrations, each
    checkpoint's true pose labelled with its achieved error, breaches, collisions and
    safety stops. The legend beside the plot lists every kind of mark drawn and only
    those; the labels are placed where they collide with nothing (:mod:`sim2d.labels`)."""
    fig, ax = plt.subplots(figsize=(12, 10), dpi=110, layout="constrained")
    # the world's labels name the checkpoints where planned; ours, at the true pose,
    # carry the errors: theirs are left out, their markers kept clear
    planned = draw_world(ax, run.robot, scans=False, cameras=False)
    colours = _controller_colours(run)
    samples = run.samples
    kinds = [controller_kind(s.controller) for s in samples]
    i = 0
    while i < len(samples) - 1:  # one line per stretch under one controller
        j = i
        while j < len(samples) - 1 and kinds[j] == kinds[i]:
            j += 1
        xy = np.array([(s.true.x, s.true.y) for s in samples[i : j + 1]])
        line = ax.plot(*xy.T, color=colours[kinds[i]], lw=1.6, zorder=6)
        tag_all(line, f"true path: {kinds[i]}")
        i = j
    if any(s.estimate is not None for s in samples):
        est = np.array(
            [(s.estimate.x, s.estimate.y) if s.estimate else (np.nan, np.nan) for s in samples]
        )
        tag_all(ax.plot(*est.T, color="black", lw=0.5, ls="--", zorder=6), "estimated path")
    _draw_tracks(ax, run)
    _draw_registration(ax, run)
    true = run.scenario.true_placement()
    labels: list[Label] = []
    poses = [true.pose_to_airport(cp.pose) for cp in run.scenario.mission.checkpoints]
    if poses:
        marks = ax.plot(
            [p.x for p in poses],
            [p.y for p in poses],
            "o",
            mfc="none",
            mec="#006d2c",
            mew=0.8,
            ms=6,
            zorder=7,
        )
        tag_all(marks, "checkpoint (true pose)")
    for cp, pose, outcome in zip(
        run.scenario.mission.checkpoints, poses, run.checkpoints, strict=True
    ):
        if outcome.position_error is not None:
            text = f"{cp.id} {outcome.position_error * 100:.0f} cm {outcome.heading_error_deg:.1f}°"
        else:
            text = f"{cp.id} {'(resumed)' if outcome.reached else 'not reached'}"
        labels.append(Label(text, pose.x, pose.y, fontsize=5.5))
    points = [(run.robot.truth.robot.x, run.robot.truth.robot.y)]
    points += [(label.x, label.y) for label in planned]
    for t, zone in run.breaches:
        s = _nearest_sample(samples, t)
        if s is not None:
            tag_all(ax.plot(s.true.x, s.true.y, "rx", ms=10, mew=2, zorder=8), "geofence breach")
            labels.append(Label(f"breach {zone}", s.true.x, s.true.y, fontsize=7, color="red"))
    for c in run.robot.truth.collisions:
        s = _nearest_sample(samples, c.time)
        if s is not None:
            tag_all(ax.plot(s.true.x, s.true.y, "k*", ms=12, zorder=8), "collision")
            points.append((s.true.x, s.true.y))
    for e in run.result.events:
        kind = e.detail.get("kind") if e.kind == "safety" else None
        s = _nearest_sample(samples, e.t) if kind in STOP_KINDS else None
        if s is not None:
            name = "e-stop" if kind == "estop-latched" else f"safety stop: {kind}"
            style = {"marker": "X", "ls": "none", "ms": 8, "mec": "black", "mew": 0.5, "zorder": 8}
            tag_all(ax.plot(s.true.x, s.true.y, color=STOP_COLOURS[kind], **style), name)
            points.append((s.true.x, s.true.y))
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.set_xlabel("x east (m)")
    ax.set_ylabel("y north (m)")
    ax.set_title(
        f"{run.scenario.mission.id} — {run.scenario.id}: {run.result.outcome} "
        f"({run.result.reason})",
        fontsize=9,
    )
    ax.grid(True, lw=0.3, alpha=0.5)
    fit_height(fig, ax)
    kinds_legend(fig, ax)
    place_labels(fig, ax, labels, avoid=points)
    return fig


STOP_COLOURS = {
    "estop-latched": "#e31a1c",
    "stale-sensor": "#ff7f00",
    "fault-stop": "#6a3d9a",
    "geofence-stop": "#b15928",
}


def _draw_tracks(ax: plt.Axes, run: DryRun) -> None:
    """Each moving tracked obstacle's path (placed with the true robot pose), dotted grey;
    red where it was on the robot's path. Static ones (the world draws them) are left out:
    a track is drawn when it travelled over 1 m at a median tracked speed over 0.3 m/s
    (the centroid of a long static face slides as the robot passes, without speed)."""
    by_id: dict[int, list] = {}
    for s in run.tracks:
        by_id.setdefault(s.id, []).append(s)
    for samples in by_id.values():
        if len(samples) < 2:
            continue
        xy = np.array([(s.x, s.y) for s in samples])
        speed = float(np.median([math.hypot(s.vx, s.vy) for s in samples]))
        if float(np.hypot(*(xy[-1] - xy[0]))) <= 1.0 or speed <= 0.3:
            continue
        line = ax.plot(*xy.T, color="0.45", lw=0.7, ls=":", zorder=5)
        tag_all(line, "tracked obstacle's path")
        danger = np.array([s.danger >= 2 for s in samples])
        if danger.any():
            dots = ax.plot(*xy[danger].T, ".", color="red", ms=2, zorder=5)
            tag_all(dots, "tracked obstacle on the robot's path")


def _draw_registration(ax: plt.Axes, run: DryRun) -> None:
    """Where the global registrations happened, and the estimated aircraft footprint at
    the end of the run (dashed) over the true one."""
    for r in run.registrations:
        if r.method != "global":
            continue
        s = _nearest_sample(run.samples, r.t)
        if s is None:
            continue
        mark = ax.plot(
            s.true.x,
            s.true.y,
            marker="D",
            ls="none",
            ms=5,
            zorder=7,
            color="green" if r.accepted else "orange",
            mec="black",
            mew=0.4,
        )
        kind = "accepted" if r.accepted else "rejected"
        tag_all(mark, f"global registration ({kind})")
    if run.final_placement is None:
        return
    for shape in run.scenario.mission.aircraft.footprint:
        pts = run.final_placement.to_airport_xy(shape.vertices(32))
        ring = np.vstack((pts, pts[:1]))
        line = ax.plot(*ring.T, color="green", lw=0.8, ls="--", zorder=6)
        tag_all(line, "footprint as registered")


def timeline(run: DryRun, path: Path | BinaryIO) -> bool:
    samples = run.samples
    if not samples:
        return False
    t = np.array([s.t for s in samples])
    safety = run.scenario.mission.safety
    fig, axes = plt.subplots(5, 1, figsize=(11, 10), dpi=100, sharex=True)
    colours = _controller_colours(run)
    names = list(colours)
    idx = np.array([names.index(controller_kind(s.controller)) for s in samples])
    axes[0].scatter(t, idx, c=[colours[names[i]] for i in idx], s=2)
    axes[0].set_yticks(range(len(names)), names, fontsize=6)
    axes[0].set_ylabel("controller")
    axes[1].plot(t, [s.v for s in samples], lw=0.8)
    axes[1].set_ylabel("v (m/s)")
    axes[2].plot(t, [s.omega for s in samples], lw=0.8)
    axes[2].set_ylabel("omega (rad/s)")
    r_c = np.array([min(s.r_c, 30.0) for s in samples])
    axes[3].plot(t, r_c, lw=0.8, label="r_c (lasers)")
    axes[3].axhline(safety.r_es, color="red", ls="--", lw=0.8, label="r_ES")
    axes[3].axhline(safety.r_oa_trigger, color="orange", ls="--", lw=0.8, label="r_OA-trigger")
    axes[3].set_ylim(0, max(6.0, safety.r_oa_trigger * 2))
    axes[3].set_ylabel("closest (m)")
    axes[3].legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.005, 1.0))
    loc = run.localisation
    if loc:
        lt = np.array([s.t for s in loc])
        axes[4].plot(lt, [s.position_error * 100 for s in loc], lw=0.8, label="pose in F error")
        axes[4].plot(lt, [s.sigma_f * 100 for s in loc], lw=0.8, ls="--", label="sigma_F (filter)")
        named: set[bool] = set()
        for r in run.registrations:
            if r.method == "global":
                verdict = "accepted" if r.accepted else "rejected"
                axes[4].axvline(
                    r.t,
                    color="green" if r.accepted else "orange",
                    lw=0.6,
                    label=None if r.accepted in named else f"global registration ({verdict})",
                )
                named.add(r.accepted)
        axes[4].set_yscale("symlog", linthresh=10.0)
        axes[4].legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.005, 1.0))
    axes[4].set_ylabel("F error (cm)")
    axes[4].set_xlabel("simulated time (s)")
    for ax in axes:
        ax.grid(True, lw=0.3, alpha=0.5)
    fig.tight_layout()
    fig.savefig(path, format="png")
    plt.close(fig)
    return True


def _something_to_plot(samples: list[AvoidanceSample]) -> bool:
    """Whether any avoidance sample has a finite value in one of the plotted rows."""
    return any(
        math.isfinite(v)
        for a in samples
        for v in (a.alpha_d, a.xi, a.beta_c, a.e_alpha, a.e_r, a.clearance)
    )


def avoidance_plot(run: DryRun, path: Path | BinaryIO) -> bool:
    """alpha_d, xi, beta_c, e_alpha, e_r (the spiral's, eqs. 4.1-4.16) and the true
    clearance against the time since each avoidance began, one colour per episode;
    velocity-obstacle and planner ticks show in the clearance panel only. No file when
    the run avoided nothing (no avoidance sample with a finite value to plot)."""
    samples = run.avoidance
    if not _something_to_plot(samples):
        return False
    episodes = sorted({a.episode for a in samples})
    rows = (
        ("alpha_d (deg)", lambda a: math.degrees(a.alpha_d)),
        ("xi (m/s)", lambda a: a.xi),
        ("beta_c (deg)", lambda a: math.degrees(a.beta_c)),
        ("e_alpha (deg)", lambda a: math.degrees(a.e_alpha)),
        ("e_r (m)", lambda a: a.e_r),
        ("clearance (m)", lambda a: a.clearance),
    )
    fig, axes = plt.subplots(len(rows), 1, figsize=(11, 12), dpi=100, sharex=True)
    for k, episode in enumerate(episodes):
        ep = [a for a in samples if a.episode == episode]
        t = np.array([a.t for a in ep]) - ep[0].t
        modes = sorted({a.mode for a in ep})
        label = f"#{episode} at {ep[0].t:.0f} s ({', '.join(modes)})"
        for ax, (_, value) in zip(axes, rows, strict=True):
            ax.plot(t, [value(a) for a in ep], lw=0.8, color=PALETTE(k % 10), label=label)
    safety = run.scenario.mission.safety
    axes[-1].axhline(safety.r_es, color="red", ls="--", lw=0.8)
    axes[2].axhline(90.0, color="grey", ls=":", lw=0.8)
    axes[2].axhline(270.0, color="grey", ls=":", lw=0.8)
    for ax, (name, _) in zip(axes, rows, strict=True):
        ax.set_ylabel(name, fontsize=8)
        ax.grid(True, lw=0.3, alpha=0.5)
    axes[0].legend(fontsize=6, loc="upper left", bbox_to_anchor=(1.005, 1.0))
    axes[-1].set_xlabel("time since the avoidance began (s)")
    fig.suptitle("obstacle avoidance episodes (spiral quantities; NaN for VO / planner)")
    fig.tight_layout()
    fig.savefig(path, format="png")
    plt.close(fig)
    return True
