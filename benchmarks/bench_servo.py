"""Servo bench: one visual-servoing scene outside the tree (issue 13, docs/servo-bench.md).

    python benchmarks/bench_servo.py --scene benchmarks/scenes/visp-ibvs-4pts.json [--json]

Runs the laws of behaviours/laws/ (servo, interaction, robot_jacobian, pose_estimation)
on a simulated pinhole camera, either free-flying (6 DoF, ViSP's vpSimulatorCamera: the
twist is integrated with the SE(3) exponential) or on the robot (q_dot = (v, omega, pan
rate, tilt rate) through the Jacobian of eq. 3.2, integrated with the thesis's Euler scheme
eq. 3.19-3.24). Prints iterations to convergence and the final errors, and next to them
the reference the scene is compared with (published figures, and optionally the same scene
run with other settings in the same process).
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from behaviours.laws.interaction import (  # noqa: E402
    pbvs_error_eq_3_25,
    project_points,
)
from behaviours.laws.pose_estimation import camera_pose_from_points  # noqa: E402
from behaviours.laws.robot_jacobian import PanTiltCamera, robot_jacobian_eq_3_2  # noqa: E402
from behaviours.laws.servo import (  # noqa: E402
    AdaptiveGain,
    InteractionAt,
    VisualServo,
    stop_algorithm_3_1,
)
from behaviours.laws.theta_u import (  # noqa: E402
    se3_exponential,
    theta_u_from_rotation,
    transform_from_pose_vector,
)
from executive.core.frames import (  # noqa: E402
    Pose2,
    Transform3,
    moved_in_aircraft,
    wrap_angle,
)

KEYS = {
    "mode",
    "camera",
    "points",
    "start",
    "desired",
    "platform",
    "law",
    "interaction",
    "gain",
    "mu",
    "dt",
    "max_iterations",
    "stop",
    "noise_px",
    "noise_relative",
    "seed",
    "switch",
    "centre_first",
    "ground_z",
    "comment",
    "reference",
}
ROBOT_KEYS = ("x", "y", "theta", "pan", "tilt")
DIVERGED_DEPTH = 1e3
"""A point this far (m) or behind the camera ends the run as diverged."""


class SceneError(ValueError):
    """A scene file that cannot be run; the message says which key and why."""


# -- the scene ---------------------------------------------------------------------------
@dataclass
class Scene:
    mode: str
    points: np.ndarray
    start: Any
    desired: Any
    camera_matrix: np.ndarray | None
    platform: PanTiltCamera
    law: str
    interaction: InteractionAt
    gain: AdaptiveGain
    mu: float | None
    dt: float
    max_iterations: int
    stop: dict[str, Any]
    noise_px: float
    noise_relative: float
    seed: int
    switch: dict[str, float]
    ground_z: float
    centre_first: dict[str, float] = field(default_factory=dict)
    reference: dict[str, Any] = field(default_factory=dict)
    raw: dict[str, Any] = field(default_factory=dict)


def _need(cond: bool, message: str) -> None:
    if not cond:
        raise SceneError(message)


def _robot_config(value: Any, key: str) -> dict[str, float]:
    _need(isinstance(value, dict), f"'{key}': robot mode wants {{x, y, theta, pan, tilt}}")
    unknown = set(value) - set(ROBOT_KEYS)
    _need(not unknown, f"'{key}': unknown keys {sorted(unknown)}; allowed {list(ROBOT_KEYS)}")
    return {k: float(value.get(k, 0.0)) for k in ROBOT_KEYS}


def _platform(value: Any) -> PanTiltCamera:
    if value is None:
        return PanTiltCamera.air_cobot("right")
    _need(isinstance(value, dict), "'platform' is an object")
    allowed = {"mount", "mount_yaw", "lateral", "optical_offset", "air_cobot"}
    unknown = set(value) - allowed
    _need(not unknown, f"'platform': unknown keys {sorted(unknown)}; allowed {sorted(allowed)}")
    if "air_cobot" in value:
        return PanTiltCamera.air_cobot(str(value["air_cobot"]))
    mount = tuple(float(v) for v in value.get("mount", (0.0, 0.0, 0.0)))
    offset = tuple(float(v) for v in value.get("optical_offset", (0.0, 0.0, 0.0)))
    _need(len(mount) == 3 and len(offset) == 3, "'platform': mount and offset are [x, y, z]")
    return PanTiltCamera(
        (mount[0], mount[1], mount[2]),
        float(value.get("mount_yaw", 0.0)),
        float(value.get("lateral", 0.0)),
        (offset[0], offset[1], offset[2]),
    )


def parse_scene(raw: dict[str, Any]) -> Scene:
    """Check a scene (the issue's format, docs/servo-bench.md) and build it."""
    _need(isinstance(raw, dict), "a scene is a JSON object")
    unknown = set(raw) - KEYS
    _need(not unknown, f"unknown keys {sorted(unknown)}; allowed {sorted(KEYS)}")
    mode = raw.get("mode")
    _need(mode in ("free-camera", "robot"), "'mode' is 'free-camera' or 'robot'")
    cam = raw.get("camera", {"normalised": True})
    if cam.get("normalised"):
        k = None
    else:
        try:
            k = np.array([[cam["fx"], 0, cam["cx"]], [0, cam["fy"], cam["cy"]], [0, 0, 1.0]])
        except KeyError as exc:
            raise SceneError(f"'camera' needs fx, fy, cx, cy or normalised: {exc}") from exc
    points = np.asarray(raw.get("points"), dtype=float)
    _need(points.ndim == 2 and points.shape[1] == 3 and len(points) >= 3, "'points': [[x,y,z]..]")
    if mode == "free-camera":
        start = transform_from_pose_vector(raw["start"])
        desired = transform_from_pose_vector(raw["desired"])
    else:
        start = _robot_config(raw.get("start"), "start")
        desired = _robot_config(raw.get("desired"), "desired")
    law = raw.get("law", "ibvs")
    _need(law in ("ibvs", "pbvs", "pbvs-ibvs"), "'law' is 'ibvs', 'pbvs' or 'pbvs-ibvs'")
    gain_raw = raw.get("gain", 0.5)
    if isinstance(gain_raw, dict):
        gain = AdaptiveGain(
            float(gain_raw["lambda_0"]), float(gain_raw["lambda_inf"]), float(gain_raw["slope_0"])
        )
    else:
        gain = AdaptiveGain.constant(float(gain_raw))
    stop = raw.get("stop", {"feature_error_sq": 1e-4})
    allowed_stops = {"feature_error_sq", "pixel_error", "algorithm_3_1"}
    _need(
        isinstance(stop, dict) and len(stop) == 1 and set(stop) <= allowed_stops,
        f"'stop' has one of {sorted(allowed_stops)}",
    )
    if "pixel_error" in stop or float(raw.get("noise_px", 0.0)) > 0.0:
        _need(k is not None, "pixel stops and noise_px need a pixel camera (fx, fy, cx, cy)")
    switch = raw.get("switch", {})
    if law == "pbvs-ibvs":
        _need(bool(switch), "'pbvs-ibvs' needs 'switch': {rotation_rad and/or translation_m}")
    centre = raw.get("centre_first", {})
    if centre:
        _need(mode == "robot", "'centre_first' needs the robot's pan-tilt unit (mode 'robot')")
        _need(set(centre) == {"centroid_error"}, "'centre_first' is {\"centroid_error\": x}")
    mu = raw.get("mu")
    return Scene(
        mode=mode,
        points=points,
        start=start,
        desired=desired,
        camera_matrix=k,
        platform=_platform(raw.get("platform")),
        law=law,
        interaction=InteractionAt(raw.get("interaction", "current")),
        gain=gain,
        mu=None if mu is None else float(mu),
        dt=float(raw.get("dt", 0.04)),
        max_iterations=int(raw.get("max_iterations", 5000)),
        stop=stop,
        noise_px=float(raw.get("noise_px", 0.0)),
        noise_relative=float(raw.get("noise_relative", 0.0)),
        seed=int(raw.get("seed", 0)),
        switch={k2: float(v) for k2, v in switch.items()},
        ground_z=float(raw.get("ground_z", 0.0)),
        centre_first={k2: float(v) for k2, v in raw.get("centre_first", {}).items()},
        reference=dict(raw.get("reference", {})),
        raw=raw,
    )


def load_scene(path: Path) -> Scene:
    try:
        raw = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise SceneError(f"{path}: {exc}") from exc
    try:
        return parse_scene(raw)
    except (SceneError, KeyError, TypeError, ValueError) as exc:
        raise SceneError(f"{path}: {exc}") from exc


# -- the simulated world -------------------------------------------------------------------
def _f_m_c(scene: Scene, config: dict[str, float]) -> Transform3:
    """Robot mode: the camera in F for a base pose in F and PTU angles."""
    pose = Pose2(config["x"], config["y"], config["theta"])
    return scene.platform.aircraft_from_camera(pose, config["pan"], config["tilt"], scene.ground_z)


def _c_m_o(scene: Scene, state: Any) -> Transform3:
    if scene.mode == "free-camera":
        return state
    return _f_m_c(scene, state).inverse()


def _advance(scene: Scene, state: Any, q_dot: np.ndarray) -> Any:
    dt = scene.dt
    if scene.mode == "free-camera":
        # wMc <- wMc exp(v dt), so cMo <- exp(v dt)^-1 cMo (vpSimulatorCamera)
        return se3_exponential(q_dot, dt).inverse() @ state
    v, w, w_pan, w_tilt = (float(c) for c in q_dot)
    # eq. 3.19-3.24: turn by omega dt, then move v dt along the new heading
    turn = w * dt
    delta = Pose2(v * dt * math.cos(turn), v * dt * math.sin(turn), turn)
    pose = moved_in_aircraft(Pose2(state["x"], state["y"], state["theta"]), delta)
    return {
        "x": pose.x,
        "y": pose.y,
        "theta": pose.theta,
        "pan": state["pan"] + w_pan * dt,
        "tilt": state["tilt"] + w_tilt * dt,
    }


def _measure(scene: Scene, xy: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """What the detector reports: normalised points with the scene's image noise."""
    out = xy.copy()
    if scene.noise_relative > 0.0:  # eq. 3.36: X (1 - r/2 + r U(0, 1)), each coordinate
        r = scene.noise_relative
        out = out * (1.0 - 0.5 * r + r * rng.random(out.shape))
    if scene.noise_px > 0.0:
        assert scene.camera_matrix is not None
        f = np.array([scene.camera_matrix[0, 0], scene.camera_matrix[1, 1]])
        out = out + rng.normal(0.0, scene.noise_px, out.shape) / f
    return out


def _pixel_error(scene: Scene, e: np.ndarray) -> float:
    assert scene.camera_matrix is not None
    f = np.array([scene.camera_matrix[0, 0], scene.camera_matrix[1, 1]])
    return float(np.max(np.linalg.norm(e.reshape(-1, 2) * f, axis=1)))


# -- the run -------------------------------------------------------------------------------
def run_scene(scene: Scene) -> dict[str, Any]:
    """Servo from start to desired; the figures of docs/servo-bench.md."""
    rng = np.random.default_rng(scene.seed)
    robot = scene.mode == "robot"
    cd_m_o = _c_m_o(scene, scene.desired)
    xy_star, z_star = project_points(cd_m_o, scene.points)
    centroid = scene.points.mean(axis=0)
    free_jacobian = np.eye(6)
    phases = (["track"] if scene.centre_first else []) + {
        "ibvs": ["ibvs"],
        "pbvs": ["pbvs"],
        "pbvs-ibvs": ["pbvs", "ibvs"],
    }[scene.law]
    phase_index = 0
    phase_starts: dict[str, int] = {phases[0]: 0}
    servo = VisualServo(scene.gain, scene.interaction, scene.mu)
    servo.switch()
    t_phase = 0.0
    state = scene.start
    pose_estimate: Transform3 | None = None
    converged = False
    reason = "max_iterations"
    law_seconds = 0.0
    loop_start = time.perf_counter()
    iteration = 0
    e = np.zeros(2 * len(scene.points))
    trajectory: list[np.ndarray] = []
    for iteration in range(scene.max_iterations + 1):
        c_m_o = _c_m_o(scene, state)
        xy, z = project_points(c_m_o, scene.points)
        if np.any(z <= 1e-6) or np.any(z > DIVERGED_DEPTH):
            reason = "diverged: a point behind the camera or beyond 1 km"
            break
        xy_meas = _measure(scene, xy, rng)
        trajectory.append(xy_meas.copy())
        e = (xy_meas - xy_star).reshape(-1)
        if phase_index + 1 < len(phases) and _phase_done(
            scene, phases[phase_index], xy_meas, xy_star, c_m_o, cd_m_o, centroid
        ):
            phase_index += 1
            phase_starts[phases[phase_index]] = iteration
            t_phase = 0.0
            servo.switch()
        phase = phases[phase_index]
        if "feature_error_sq" in scene.stop and float(e @ e) < scene.stop["feature_error_sq"]:
            converged, reason = True, "feature_error_sq"
            break
        if "pixel_error" in scene.stop and _pixel_error(scene, e) < scene.stop["pixel_error"]:
            converged, reason = True, "pixel_error"
            break
        if iteration == scene.max_iterations:
            break
        jacobian = (
            robot_jacobian_eq_3_2(scene.platform, state["pan"], state["tilt"])
            if robot
            else free_jacobian
        )
        tick = time.perf_counter()
        if phase == "track":
            step = servo.track_feature_step(xy_meas, z, jacobian, t_phase, xy_star.mean(axis=0))
        elif phase == "ibvs":
            step = servo.ibvs_step(xy_meas, z, xy_star, z_star, jacobian, t_phase)
        else:
            pixels = xy_meas if scene.camera_matrix is None else _to_pixels(scene, xy_meas)
            pose_estimate = camera_pose_from_points(
                scene.points, pixels, scene.camera_matrix, pose_estimate
            )
            step = servo.pbvs_step(pose_estimate, cd_m_o, jacobian, t_phase, centroid)
        law_seconds += time.perf_counter() - tick
        if "algorithm_3_1" in scene.stop and phase_index == len(phases) - 1:
            cfg = scene.stop["algorithm_3_1"]
            if stop_algorithm_3_1(
                step.q_dot,
                iteration - phase_starts[phase],
                int(cfg["min_iterations"]),
                cfg["threshold"],
            ):
                converged, reason = True, "algorithm_3_1"
                break
        state = _advance(scene, state, step.q_dot)
        t_phase += scene.dt
    loop_seconds = time.perf_counter() - loop_start
    steps = max(iteration, 1)
    result: dict[str, Any] = {
        "converged": converged,
        "stop_reason": reason,
        "iterations": iteration,
        "final_feature_error": float(e @ e),
        **pose_errors(scene, state),
        "ms_per_iteration": 1e3 * loop_seconds / steps,
        "ms_per_law_step": 1e3 * law_seconds / steps,
    }
    if scene.camera_matrix is not None:
        result["final_pixel_error"] = _pixel_error(scene, e)
    if len(phases) > 1:
        result["phase_starts"] = phase_starts
    result["_trajectory"] = trajectory
    result["_final_state"] = state
    return result


def _phase_done(
    scene: Scene,
    phase: str,
    xy: np.ndarray,
    xy_star: np.ndarray,
    c_m_o: Transform3,
    cd_m_o: Transform3,
    centroid: np.ndarray,
) -> bool:
    """Whether the current phase hands over to the next one."""
    if phase == "track":
        error = np.linalg.norm(xy.mean(axis=0) - xy_star.mean(axis=0))
        return bool(error < scene.centre_first["centroid_error"])
    if phase == "pbvs":
        return _switch_now(scene.switch, pbvs_error_eq_3_25(c_m_o, cd_m_o, centroid))
    return False


def pose_errors(scene: Scene, state: Any) -> dict[str, Any]:
    """Final errors of a state (free: ``cMo``; robot: configuration) against the desired
    one: the camera pose, and in robot mode the base pose and PTU angles as well."""
    c_m_cd = _c_m_o(scene, state) @ _c_m_o(scene, scene.desired).inverse()
    out: dict[str, Any] = {
        "final_position_error_m": float(np.linalg.norm(c_m_cd.translation)),
        "final_rotation_error_rad": float(np.linalg.norm(theta_u_from_rotation(c_m_cd.rotation))),
    }
    if scene.mode == "robot":
        d = scene.desired
        out["final_robot_error"] = {
            "position_m": math.hypot(state["x"] - d["x"], state["y"] - d["y"]),
            "x_m": abs(state["x"] - d["x"]),
            "y_m": abs(state["y"] - d["y"]),
            "heading_rad": abs(wrap_angle(state["theta"] - d["theta"])),
            "pan_rad": abs(wrap_angle(state["pan"] - d["pan"])),
            "tilt_rad": abs(wrap_angle(state["tilt"] - d["tilt"])),
        }
    return out


def published_errors(scene: Scene) -> dict[str, Any]:
    """The reference's published figures, plus the errors of its published final robot
    configuration (``published_final``) computed through the same camera chain."""
    out = dict(scene.reference.get("published", {}))
    final = scene.reference.get("published_final")
    if final is not None:
        out.update(pose_errors(scene, _robot_config(final, "reference.published_final")))
    return out


def _switch_now(switch: dict[str, float], e_p: np.ndarray) -> bool:
    ok = True
    if "rotation_rad" in switch:
        ok &= float(np.linalg.norm(e_p[3:])) < switch["rotation_rad"]
    if "translation_m" in switch:
        ok &= float(np.linalg.norm(e_p[:3])) < switch["translation_m"]
    return ok


def _to_pixels(scene: Scene, xy: np.ndarray) -> np.ndarray:
    k = scene.camera_matrix
    assert k is not None
    return np.column_stack((k[0, 2] + k[0, 0] * xy[:, 0], k[1, 2] + k[1, 1] * xy[:, 1]))


def reference_runs(scene: Scene) -> list[tuple[str, dict[str, Any]]]:
    """The scene re-run with each of the reference's overrides (same process, same run)."""
    runs = []
    for item in scene.reference.get("runs", []):
        raw = copy.deepcopy(scene.raw)
        raw.pop("reference", None)
        raw.update(item["overrides"])
        runs.append((str(item["label"]), run_scene(parse_scene(raw))))
    return runs


def public(result: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in result.items() if not k.startswith("_")}


# -- one servo step ---------------------------------------------------------------------------
STEP_BUDGET_MS = 1.0
"""The tree's budget for one servo step (issue 13): well under a 10 Hz tick's 100 ms."""


def step_timing(repeat: int = 2000) -> dict[str, float]:
    """Median cost (ms) of one servo step for 4 points and the 4 DoF of the robot: the
    Jacobian of eq. 3.2, the interaction matrices and the law (IBVS, L mean, adaptive
    gain, continuous sequencing) -- and PBVS including solvePnP (IPPE)."""
    camera = PanTiltCamera.air_cobot("right")
    points = np.array([[1.5, -0.05, -0.765], [1.5, 0.05, -0.765], [1.5, 0.05, -0.665]])
    points = np.vstack((points, [[1.5, -0.05, -0.665]]))
    config = {"x": -0.4, "y": 0.05, "theta": 0.1, "pan": -0.2, "tilt": 0.1}
    desired = {"x": 0.0, "y": 0.0, "theta": 0.0, "pan": 0.0, "tilt": 0.0}
    scene = parse_scene(
        {
            "mode": "robot",
            "points": points.tolist(),
            "start": config,
            "desired": desired,
        }
    )
    c_m_o, cd_m_o = _c_m_o(scene, config), _c_m_o(scene, desired)
    xy, z = project_points(c_m_o, points)
    xy_star, z_star = project_points(cd_m_o, points)
    servo = VisualServo(AdaptiveGain(4.0, 0.4, 30.0), InteractionAt.MEAN, mu=4.0)
    servo.switch()

    def ibvs() -> None:
        jacobian = robot_jacobian_eq_3_2(camera, config["pan"], config["tilt"])
        servo.ibvs_step(xy, z, xy_star, z_star, jacobian, 0.1)

    def pbvs() -> None:
        jacobian = robot_jacobian_eq_3_2(camera, config["pan"], config["tilt"])
        estimate = camera_pose_from_points(points, xy, None, c_m_o)
        servo.pbvs_step(estimate, cd_m_o, jacobian, 0.1, points.mean(axis=0))

    out = {}
    for name, fn in (("ibvs_step_ms", ibvs), ("pbvs_step_with_solvepnp_ms", pbvs)):
        samples = []
        for _ in range(repeat):
            tick = time.perf_counter()
            fn()
            samples.append(time.perf_counter() - tick)
        out[name] = 1e3 * float(np.median(samples))
    return out


# -- output --------------------------------------------------------------------------------
def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.3g}"
    if isinstance(value, dict):
        return ", ".join(f"{k} {_fmt(v)}" for k, v in value.items())
    return str(value)


def plot_image_plane(scene: Scene, result: dict[str, Any], path: Path) -> None:
    """The measured image points along the run (one line per point), from the start (o)
    to the desired features (x): the picture of an IBVS/PBVS run in the image."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    track = np.array(result["_trajectory"])  # (iterations, N, 2) normalised
    desired, _ = project_points(_c_m_o(scene, scene.desired), scene.points)
    if scene.camera_matrix is not None:
        track = np.array([_to_pixels(scene, xy) for xy in track])
        desired = _to_pixels(scene, desired)
        unit = "px"
    else:
        unit = "normalised"
    fig, ax = plt.subplots(figsize=(5.5, 4.5))
    for k in range(track.shape[1]):
        (line,) = ax.plot(track[:, k, 0], track[:, k, 1], lw=1.2)
        ax.plot(*track[0, k], "o", color=line.get_color())
        ax.plot(*desired[k], "x", color="black", ms=9)
    ax.set_xlabel(f"u ({unit})")
    ax.set_ylabel(f"v ({unit})")
    ax.invert_yaxis()
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_title(f"{path.stem}: {result['iterations']} iterations (o start, x desired)")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", type=Path, help="scene file (JSON)")
    parser.add_argument("--json", action="store_true", help="print the figures as JSON")
    parser.add_argument(
        "--plot", type=Path, help="write the image-plane trajectories of the points (PNG)"
    )
    parser.add_argument(
        "--step-timing", action="store_true", help="time one servo step (4 points, 4 DoF)"
    )
    args = parser.parse_args(argv)
    if args.step_timing:
        timing = step_timing()
        if args.json:
            print(json.dumps({**timing, "budget_ms": STEP_BUDGET_MS}, indent=2))
        else:
            for key, value in timing.items():
                print(f"{key:28s} {value:.3f} ms (median of 2000)")
            print(f"{'reference: budget':28s} {STEP_BUDGET_MS:.3f} ms per step (issue 13)")
        return 0
    if args.scene is None:
        parser.error("--scene FILE.json is required (or --step-timing)")
    try:
        scene = load_scene(args.scene)
    except SceneError as exc:
        print(f"bench_servo: {exc}", file=sys.stderr)
        return 2
    result = run_scene(scene)
    if args.plot is not None:
        plot_image_plane(scene, result, args.plot)
    ours = public(result)
    runs = [(label, public(r)) for label, r in reference_runs(scene)]
    published = published_errors(scene)
    source = scene.reference.get("source", "")
    if args.json:
        out = {"scene": str(args.scene), "ours": ours}
        if published or runs:
            out["reference"] = {
                "source": source,
                "published": published,
                "runs": {label: r for label, r in runs},
            }
        print(json.dumps(out, indent=2))
        return 0
    print(f"scene {args.scene}")
    if "comment" in scene.raw:
        print(f"  {scene.raw['comment']}")
    print(f"ours: {'converged' if ours['converged'] else 'NOT converged'} ({ours['stop_reason']})")
    for key, value in ours.items():
        if key not in ("converged", "stop_reason"):
            print(f"  {key:28s} {_fmt(value)}")
    if published:
        print(f"reference: {source}")
        for key, value in published.items():
            print(f"  {key:28s} {_fmt(value)}")
    for label, r in runs:
        state = "converged" if r["converged"] else "NOT converged"
        print(f"reference run, {label}: {state} ({r['stop_reason']})")
        for key in ("iterations", "final_feature_error", "final_position_error_m"):
            print(f"  {key:28s} {_fmt(r[key])}")
        if "final_robot_error" in r:
            print(f"  {'final_robot_error':28s} {_fmt(r['final_robot_error'])}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
