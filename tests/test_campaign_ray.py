"""The Ray backend of `walkaround campaign` (issue 16): on a local Ray instance, the same
episodes give the same rows as the local backend's processes (apart from the wall time),
and an episode whose task raises or whose worker dies is a crashed row."""

import json
import os
import shutil
import sys

import pytest
import ray

from executive.campaign.ray_backend import ray_crashed_row
from executive.campaign.results import RESULTS_FILE, read_rows
from executive.campaign.runner import run_campaign
from executive.campaign.spec import load_campaign
from executive.cli import main
from tests.conftest import MISSIONS

# one Ray instance for the module, in the xdist group of the real-time (HIL) tests: Ray
# starts processes of its own (raylet, GCS, workers) and opens ports, which starved the HIL
# rig's processes and took a port it had picked when both ran at once on 2 cores
pytestmark = [pytest.mark.xdist_group("hil"), pytest.mark.slow]

LEG = MISSIONS / "campaigns" / "avoidance-leg.xml"
EPISODES = 4
MAX_TIME = 3.0


@pytest.fixture(scope="module")
def ray_instance():
    """A local Ray instance of two CPUs, which the backend uses as it finds it."""
    os.environ.pop("RAY_ADDRESS", None)
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield
    ray.shutdown()


def _without_wall(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if k != "wall_s"} for r in rows]


def test_ray_rows_equal_the_local_rows(ray_instance, tmp_path):
    campaign = load_campaign(LEG)
    local = run_campaign(campaign, tmp_path / "local", EPISODES, jobs=2, max_time=MAX_TIME)
    remote = run_campaign(
        campaign, tmp_path / "ray", EPISODES, jobs=2, max_time=MAX_TIME, backend="ray"
    )
    assert [r["episode"] for r in remote] == list(range(EPISODES))
    assert not any(r["outcome"] == "crashed" for r in remote), remote
    assert _without_wall(remote) == _without_wall(local)
    assert ray.is_initialized()  # an instance the caller started is left running
    # the folder is the local backend's: summary, and --resume through the command line
    # with a shard (episodes 1 and 3 already there: nothing to rerun)
    summary = json.loads((tmp_path / "ray" / "summary.json").read_text())
    assert summary["episodes"] == EPISODES
    out = tmp_path / "cli"
    args = ["campaign", str(LEG), "--out", str(out), "--episodes", str(EPISODES)]
    args += ["--max-time", str(MAX_TIME), "--backend", "ray", "--jobs", "2", "--quiet"]
    assert main([*args, "--shard", "1/2"]) in (0, 1)
    assert sorted(r["episode"] for r in read_rows(out / RESULTS_FILE)) == [1, 3]
    assert main([*args, "--shard", "1/2", "--resume"]) in (0, 1)
    rows = read_rows(out / RESULTS_FILE)
    assert sorted(r["episode"] for r in rows) == [1, 3]
    assert _without_wall(sorted(rows, key=lambda r: r["episode"])) == _without_wall(
        [local[1], local[3]]
    )


def test_episodes_whose_files_differ_on_the_worker_crash(ray_instance, tmp_path):
    lib = tmp_path / "lib"
    shutil.copytree(MISSIONS / "track", lib / "track")
    (lib / "campaigns").mkdir()
    shutil.copy(LEG, lib / "campaigns" / "leg.xml")
    campaign = load_campaign(lib / "campaigns" / "leg.xml")
    # after the driver loaded it, the file changes (another copy on a cluster node) ...
    path = lib / "campaigns" / "leg.xml"
    path.write_text(path.read_text().replace('speed-max="0.6"', 'speed-max="0.5"'))
    rows = run_campaign(campaign, tmp_path / "changed", 2, max_time=MAX_TIME, backend="ray")
    assert [r["outcome"] for r in rows] == ["crashed", "crashed"]
    assert "differ in this worker" in rows[0]["first_cause"]
    # ... or breaks: the task's load raises, and the episode is a crashed row
    (lib / "track" / "scenarios" / "avoidance-leg.xml").write_text("<scenario")
    rows = run_campaign(campaign, tmp_path / "broken", 2, max_time=MAX_TIME, backend="ray")
    assert [r["outcome"] for r in rows] == ["crashed", "crashed"]
    assert "InvalidInputError" in rows[0]["first_cause"] and rows[0]["traceback"]


def test_a_raising_task_and_a_dead_worker_are_crashed_rows(ray_instance):
    campaign = load_campaign(LEG)

    @ray.remote(max_retries=0)
    def raises():
        raise RuntimeError("simulated crash")

    @ray.remote(max_retries=0)
    def dies():
        os._exit(3)

    with pytest.raises(ray.exceptions.RayError) as raised:
        ray.get(raises.remote())
    row = ray_crashed_row(campaign, 5, raised.value)
    assert row["episode"] == 5 and row["outcome"] == "crashed" and not row["succeeded"]
    assert row["first_cause"] == "crashed: RuntimeError: simulated crash"
    assert "simulated crash" in row["traceback"]
    with pytest.raises(ray.exceptions.RayError) as died:
        ray.get(dies.remote())
    row = ray_crashed_row(campaign, 6, died.value)
    assert row["outcome"] == "crashed" and "worker died" in row["first_cause"]
    assert row["campaign"] == campaign.id


def test_without_ray_the_backend_asks_for_the_extra(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` fails
    out = tmp_path / "o"
    assert main(["campaign", str(LEG), "--out", str(out), "--backend", "ray"]) == 2
    assert "pip install 'walkaround[cluster]'" in capsys.readouterr().err
    assert not out.exists()
    assert main(["campaign", str(LEG), "--out", str(out), "--ray-address", "auto"]) == 2
    assert "--ray-address goes with --backend ray" in capsys.readouterr().err
