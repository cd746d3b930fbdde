"""What recording for Foxglove costs a dry-run (issue 15 §5; aim: under 5 % slower).

Usage:  OPENBLAS_NUM_THREADS=1 python benchmarks/bench_recording.py [--seconds 300]
            [--repeat 3] [--scenario clear-apron] [--out DIR]

The A320 pre-flight dry-run on SCENARIO (default the clear apron), its first SECONDS
simulated seconds, without a recording (the reference) and with one
(``dry_run(..., record=...)``, as ``walkaround dry-run`` does by default), back to back,
REPEAT times in alternation so that a busy machine slows both alike. Printed: the wall
time of each run, the cost (the median of the pairs' differences, and the best run
against the best run), the time spent in the recorder's tick hook, the MCAP's size and
bytes per simulated second, and the share of each topic in it (uncompressed).
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from collections import Counter
from pathlib import Path

from mcap.reader import make_reader

import executive.recording as recording
from executive.core.resources import missions_dir
from executive.dryrun import dry_run
from sim2d.scenario import load_scenario


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=300.0, help="simulated seconds")
    parser.add_argument("--repeat", type=int, default=3, help="pairs of runs")
    parser.add_argument("--scenario", default="clear-apron", help="an A320 scenario")
    parser.add_argument("--out", type=Path, default=None, help="keep the MCAP here")
    args = parser.parse_args()
    scenario = load_scenario(missions_dir() / "a320" / "scenarios" / f"{args.scenario}.xml")
    folder = args.out or Path(tempfile.mkdtemp(prefix="bench-recording-"))
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "run.mcap"

    hook = [0.0]
    on_tick = recording.Recorder.on_tick

    def timed(self: recording.Recorder, *a: object) -> None:
        t0 = time.perf_counter()
        on_tick(self, *a)  # type: ignore[arg-type]
        hook[0] += time.perf_counter() - t0

    recording.Recorder.on_tick = timed  # type: ignore[method-assign]

    print(
        f"A320 {args.scenario}, first {args.seconds:g} simulated s, {args.repeat} pairs "
        "(reference: the same dry-run without recording)"
    )
    print(f"{'pair':>4}  {'without (s)':>11}  {'with (s)':>9}  {'cost':>7}  {'hook (s)':>8}")
    without, with_, hooks = [], [], []
    for k in range(args.repeat):
        ref = dry_run(scenario, max_time=args.seconds)
        hook[0] = 0.0
        rec = dry_run(scenario, max_time=args.seconds, record=path)
        assert rec.recording_error is None, rec.recording_error
        without.append(ref.wall_time)
        with_.append(rec.wall_time)
        hooks.append(hook[0])
        cost = (rec.wall_time / ref.wall_time - 1.0) * 100.0
        print(
            f"{k + 1:>4}  {ref.wall_time:>11.2f}  {rec.wall_time:>9.2f}  {cost:>6.1f}%  "
            f"{hook[0]:>8.2f}"
        )
    paired = statistics.median((w / r - 1.0) * 100.0 for w, r in zip(with_, without, strict=True))
    best = (min(with_) / min(without) - 1.0) * 100.0
    hook_share = statistics.median(h / w * 100.0 for h, w in zip(hooks, with_, strict=True))
    print(f"cost: median of pairs {paired:+.1f} %, best against best {best:+.1f} %")
    print(f"time in the recorder's tick hook: {hook_share:.1f} % of the recorded run")

    size = path.stat().st_size
    topics: Counter[str] = Counter()
    counts: Counter[str] = Counter()
    with path.open("rb") as f:
        reader = make_reader(f)
        for _, channel, message in reader.iter_messages():
            topics[channel.topic] += len(message.data)
            counts[channel.topic] += 1
    raw = sum(topics.values())
    print(
        f"MCAP: {size / 1e6:.2f} MB ({size / args.seconds / 1e3:.1f} kB per simulated s), "
        f"{sum(counts.values())} messages, {raw / 1e6:.1f} MB uncompressed "
        f"(zstd x{raw / size:.0f}); {path}"
    )
    print(f"{'topic':<32} {'messages':>8} {'MB raw':>7} {'share':>6}")
    for topic, nbytes in topics.most_common():
        print(f"{topic:<32} {counts[topic]:>8} {nbytes / 1e6:>7.2f} {nbytes / raw:>6.1%}")


if __name__ == "__main__":
    main()
