"""Draft missions (`walkaround plan`, issue 18) against the hand-written ones.

Usage:  OPENBLAS_NUM_THREADS=1 python benchmarks/bench_plan.py [--dry-run] [--repeat N]
            [--json OUT.json] [TYPE ...]   (TYPE: a320, b737-800, lab; default all three)

For each aircraft type of the shipped library, plans a draft with the type's shipped
mission as the template (the same robot, zones, station and parking), writes it next to a
copy of the aircraft file in a temporary library, validates it with the loader, and prints
side by side, draft vs hand-written: checkpoints, items assigned, inspection tour length
(P round the checkpoints back to P), whole route length (station and back), and the
planner's time (median of N), checkpoints with a servo target, total dwell. With --dry-run,
both missions are also dry-run on the type's clear-apron scenario (servoing as
`walkaround dry-run` defaults it): simulated mission time, items inspected (detected with
a fresh image), checkpoints finished by visual servoing, the worst checkpoint error on
ground truth, collisions and geofence breaches, success. --json writes every figure.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
import statistics
import tempfile
import time
from pathlib import Path

from executive.core.loader import load_aircraft, load_mission
from executive.core.model import Mission
from executive.core.resources import missions_dir
from executive.planning.plan import inspection_tour_length, plan_mission, route_length
from executive.planning.write import write_mission

TEMPLATES = {
    "a320": "preflight.xml",
    "b737-800": "preflight.xml",
    "lab": "visual-servoing.xml",
}


def dry_run_figures(mission: Mission, library: Path) -> dict[str, object]:
    """Dry-run ``mission`` on its type's clear-apron scenario: time, items, success."""
    from executive.dryrun import dry_run
    from sim2d.scenario import load_scenario

    scenario = load_scenario(library / "scenarios" / "clear-apron.xml")
    scenario = dataclasses.replace(scenario, mission=mission)
    wall0 = time.perf_counter()
    run = dry_run(scenario)
    wall = time.perf_counter() - wall0
    results = run.result.progress.results
    names = [e.detail["to"] for e in run.result.events if e.kind == "controller"]
    servoed = 0
    for cp in mission.checkpoints:
        if cp.target is None or f"inspect {cp.id}" not in names:
            continue
        before = [
            n for n in names[: names.index(f"inspect {cp.id}")] if not n.startswith("correct ")
        ]
        servoed += bool(before) and before[-1].startswith("visual servoing (")
    reached = [c for c in run.checkpoints if c.reached]
    return {
        "outcome": run.result.outcome,
        "succeeded": run.succeeded,
        "mission_s": run.robot.time,
        "items": sum(1 for r in results if r.detected),
        "checkpoints_reached": len(reached),
        "servoed": servoed,
        "worst_position_error_m": max((c.position_error for c in reached), default=None),
        "worst_heading_error_deg": max((c.heading_error_deg for c in reached), default=None),
        "collisions": len(run.robot.truth.collisions),
        "breaches": len(run.breaches),
        "warnings": [w for w in run.warnings if "servo" in w],
        "wall_s": wall,
        "cause": run.first_cause,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("types", nargs="*", default=list(TEMPLATES), metavar="TYPE")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--dry-run", action="store_true")
    parser.add_argument("--json", type=Path, default=None, metavar="OUT.json")
    args = parser.parse_args()

    report: dict[str, object] = {}
    for kind in args.types:
        library = missions_dir() / kind
        template_path = library / TEMPLATES[kind]
        hand = load_mission(template_path)
        aircraft = load_aircraft(library / "aircraft.xml")
        times = []
        for _ in range(max(1, args.repeat)):
            t0 = time.perf_counter()
            plan = plan_mission(hand, aircraft)
            times.append(time.perf_counter() - t0)
        with tempfile.TemporaryDirectory() as tmp:
            folder = Path(tmp) / kind
            folder.mkdir()
            shutil.copy(library / "aircraft.xml", folder / "aircraft.xml")
            out = folder / "draft.xml"
            write_mission(plan, template_path, folder / "aircraft.xml", out)
            draft = load_mission(out)  # raises if the draft does not validate
        n_items = len(aircraft.items)
        rows = [
            ("checkpoints", len(draft.checkpoints), len(hand.checkpoints)),
            (
                f"items assigned (of {n_items})",
                sum(len(c.items) for c in draft.checkpoints),
                len({i for c in hand.checkpoints for i in c.items}),
            ),
            ("inspection tour (m)", inspection_tour_length(draft), inspection_tour_length(hand)),
            ("whole route (m)", route_length(draft), route_length(hand)),
            (
                "servo targets",
                sum(1 for c in draft.checkpoints if c.target),
                sum(1 for c in hand.checkpoints if c.target),
            ),
            (
                "total dwell (s)",
                float(sum(c.dwell for c in draft.checkpoints)),
                float(sum(c.dwell for c in hand.checkpoints)),
            ),
            (
                "via points",
                sum(len(c.via) for c in draft.checkpoints),
                sum(len(c.via) for c in hand.checkpoints),
            ),
        ]
        print(f"\n== {aircraft.type} ({kind}): draft vs hand-written {template_path.name}")
        print(
            f"planner: {plan.candidates} candidate poses, median {statistics.median(times):.2f} s "
            f"over {len(times)} (min {min(times):.2f} s); uncovered: "
            + (", ".join(plan.uncovered) or "none")
        )
        for item, reason in plan.uncovered.items():
            print(f"  {item}: {reason}")
        if args.dry_run:
            figs = {}
            for label, mission in (("draft", draft), ("hand-written", hand)):
                figs[label] = fig = dry_run_figures(mission, library)
                print(
                    f"  dry-run {label}: {fig['outcome']}, succeeded {fig['succeeded']}, "
                    f"wall {fig['wall_s']:.0f} s"
                    + (f", first cause: {fig['cause']}" if fig["cause"] else "")
                )
            d, h = figs["draft"], figs["hand-written"]
            rows.append(("dry-run mission time (s)", d["mission_s"], h["mission_s"]))
            rows.append(("dry-run items inspected", d["items"], h["items"]))
            rows.append(("dry-run servoed checkpoints", d["servoed"], h["servoed"]))
            for key, label in (
                ("worst_position_error_m", "worst checkpoint error (m)"),
                ("worst_heading_error_deg", "worst checkpoint error (deg)"),
            ):
                rows.append((label, d[key], h[key]))
            rows.append(
                (
                    "collisions / breaches",
                    f"{d['collisions']}/{d['breaches']}",
                    f"{h['collisions']}/{h['breaches']}",
                )
            )
            report_dry = figs
        else:
            report_dry = None
        report[kind] = {
            "type": aircraft.type,
            "template": template_path.name,
            "candidates": plan.candidates,
            "planner_s_median": statistics.median(times),
            "planner_s_min": min(times),
            "uncovered": plan.uncovered,
            "rows": {name: {"draft": a, "hand-written": b} for name, a, b in rows},
            "dry_run": report_dry,
        }
        print(f"  {'':34s} {'draft':>10s} {'hand-written':>13s}")
        for name, a, b in rows:
            print(f"  {name:34s} {_fmt(a):>10s} {_fmt(b):>13s}")
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(report, indent=2, default=str) + "\n")
        print(f"\nwrote {args.json}")


def _fmt(value: object) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:.3f}" if abs(value) < 1 else f"{value:.1f}"
    return str(value)


if __name__ == "__main__":
    main()
