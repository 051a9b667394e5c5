"""The pipeline's jobs give the same bytes as Ray tasks as in local processes."""

from __future__ import annotations

import os

import numpy as np
import pytest
import yaml

from replicate.core import executor
from replicate.core.artifacts import read_curve
from replicate.core.params import load_params
from replicate.core.schema import ConfigError
from replicate.learn.train import CURVE, load_actors
from replicate.pipeline.matrix import train_matrix

from ..conftest import ROOT


@pytest.fixture(scope="module")
def ray_local():
    """A local Ray runtime of two CPUs (a cluster's address in RAY_ADDRESS is not used here)."""
    pytest.importorskip("ray")
    saved = os.environ.pop("RAY_ADDRESS", None)
    ray = executor.ray_runtime(num_cpus=2)
    yield ray
    ray.shutdown()
    if saved is not None:
        os.environ["RAY_ADDRESS"] = saved


def tiny_params(tmp_path):
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    params["train"].update(seeds={"paper": [0], "tuned": [3, 4]}, checkpoint_every=20)
    params["configs"]["tuned"].update(n_envs=10)
    params["configs"]["tuned"]["maddpg"].update(learning_starts=500, batch_size=32)
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump(params, sort_keys=False))
    return str(path)


@pytest.mark.slow
def test_a_train_matrix_through_ray_is_the_local_matrix(ray_local, tmp_path):
    """Two cells (tuned SW and CR on the square, seeds 3 and 4, 40 episodes) as Ray tasks and in local processes:
    every curve column and every actor parameter equal to the last bit."""
    path = tiny_params(tmp_path)
    runs = {}
    for name in executor.EXECUTORS:
        _, table = train_matrix(path, ["tuned"], ["sw", "cr"], ["square"], 40, str(tmp_path / name), 2,
                                executor=name)
        assert len(table) == 4 and not any(r["skipped"] for r in table)
        runs[name] = sorted(p for p in (tmp_path / name).iterdir() if p.is_dir())
    assert [p.name for p in runs["local"]] == [p.name for p in runs["ray"]]
    for local, remote in zip(runs["local"], runs["ray"]):
        a, b = read_curve(local / CURVE), read_curve(remote / CURVE)
        assert a.keys() == b.keys()
        for column in a:
            np.testing.assert_array_equal(a[column], b[column], err_msg=f"{local.name}: {column}")
        for p, q in zip(load_actors(local / "actors.pt")[0].parameters(),
                        load_actors(remote / "actors.pt")[0].parameters()):
            assert p.equal(q), local.name


@pytest.mark.slow
def test_ray_runs_optuna_trials_as_tasks(ray_local, tmp_path):
    """A naive-swarming study of 4 trials on the square, each trial a Ray task: every trial completes with its
    value and CPU seconds in a SQLite study another process could join."""
    import optuna

    from replicate.compare.tuning import tune_baseline
    from replicate.learn.fingerprint import search_fingerprint
    from replicate.world.regions import make_region

    storage = f"sqlite:///{tmp_path / 'study.db'}"
    params = load_params(ROOT / "params.yaml", {"tuning.baselines.storage": storage,
                                                "tuning.baselines.naive.trials": 4, "tuning.starts": 4})
    region = make_region("square", params.regions["square"], params.world.region_area)
    result = tune_baseline(params, region, "naive", executor="ray")
    study = optuna.load_study(study_name=result["study"], storage=storage)
    assert all(0 < t.value <= 1 and t.user_attrs["cpu_seconds"] > 0 for t in study.trials)
    # a trial on the square takes a few hundredths of a second: the budget's sum is rounded to a tenth
    spent = round(sum(t.user_attrs["cpu_seconds"] for t in study.trials), 1)
    assert result["trials"] == 4 and result["failed_trials"] == 0 and result["cpu_seconds"] == spent
    assert {t.user_attrs["arithmetic"] for t in study.trials} == {search_fingerprint()}  # the sampler's process


def test_an_unknown_executor_is_refused_by_name():
    with pytest.raises(ConfigError, match="executor must be one of local, ray, got 'dask'"):
        executor.map_jobs(len, [[1]], "dask")


def test_ctrl_c_stops_the_workers_at_once(tmp_path):
    """Ctrl-C to the main process alone (as a supervisor sends it) ends a map of long jobs within seconds: its
    worker processes are terminated, not waited for."""
    import signal
    import subprocess
    import sys
    import time

    from ..command import default_sigint

    code = ("import pathlib, sys, time\nfrom replicate.core.executor import map_jobs\n"
            "def job(i):\n    pathlib.Path(sys.argv[1], f'started-{i}').touch()\n    time.sleep(60)\n"
            "map_jobs(job, [0, 1], 'local', 2)\n")
    proc = subprocess.Popen([sys.executable, "-c", code, str(tmp_path)], stderr=subprocess.PIPE, text=True,
                            preexec_fn=default_sigint)  # a suite run in the background ignores SIGINT otherwise
    deadline = time.monotonic() + 120
    while len(list(tmp_path.glob("started-*"))) < 2 and time.monotonic() < deadline:
        time.sleep(0.05)
    assert len(list(tmp_path.glob("started-*"))) == 2, "both workers run a job"
    start = time.monotonic()
    proc.send_signal(signal.SIGINT)
    proc.wait(timeout=60)
    assert time.monotonic() - start < 10 and "KeyboardInterrupt" in proc.stderr.read()


def test_beside_returns_a_closures_value_or_raises_its_error():
    """``Beside`` runs a closure in a forked process (evaluate --policy runs Lloyd's episodes so)."""
    from replicate.core.executor import Beside

    data = list(range(1000))
    assert Beside(lambda: sum(x * x for x in data)).result() == sum(x * x for x in data)
    with pytest.raises(ZeroDivisionError):
        Beside(lambda: 1 / 0).result()
