"""A policy on a buoy's computer (``toolkit.deploy``): the control contract, SI observations, the stream of steps."""

from __future__ import annotations

import io
import json

import numpy as np
import pytest

from replicate.core.params import packaged
from replicate.learn.policy import load_policy
from replicate.toolkit.deploy import Actor, act, export_for, stream
from replicate.world.units import Units, from_simulation


@pytest.fixture(scope="module")
def sim_obs():
    """Observations of 9 buoys in simulation units, as the general policy reads them."""
    rng = np.random.default_rng(0)
    obs = rng.uniform(0, 1.5, size=(9, 22))
    obs[:, 10:14] = rng.integers(0, 2, size=(9, 4))
    return obs


def test_a_policy_exported_for_a_deployment_carries_its_contract(params, tmp_path, sim_obs):
    """25 m buoys at 1 m/s: the contract states a 14.14 s control period, 100 m radio and shore ranges, the unit of
    every input column; read in SI with that contract, the policy commands what it commands in simulation units."""
    units = Units.of(params.world, params.coverage, 25.0, 1.0)
    meta = export_for(packaged("general.pt"), tmp_path / "buoy.pt", params, units)
    si = meta["contract"]["si"]
    assert si["control_period_s"] == pytest.approx(14.1421, abs=1e-4) and si["comm_range_m"] == pytest.approx(100)
    assert si["top_speed_ms"] == pytest.approx(1.0) and si["radius_m"] == pytest.approx(25.0)
    inputs = meta["contract"]["inputs"]
    assert [c["name"] for c in inputs] == meta["observation_layout"]
    assert {c["unit"] for c in inputs} == {"m/s", "m", "1"}
    assert "nearest first" in meta["contract"]["neighbour_order"] and "v <- (1 - damping)" in meta["contract"]["action"]
    _, loaded = load_policy(tmp_path / "buoy.pt")  # the checksum holds over the new metadata
    assert loaded["contract"] == json.loads(json.dumps(meta["contract"]))
    columns = meta["observation_layout"]
    in_si = from_simulation(sim_obs, columns, units)
    expected = act(packaged("general.pt"), sim_obs)
    np.testing.assert_allclose(act(tmp_path / "buoy.pt", in_si, real=True), expected, atol=1e-5)
    np.testing.assert_allclose(act(packaged("general.pt"), in_si, real=True, units=units), expected, atol=1e-5)


def test_a_general_policy_refuses_si_without_its_scale(sim_obs):
    with pytest.raises(ValueError, match="give the deployment's --radius-m and --speed-ms"):
        Actor(packaged("general.pt"), real=True)


def test_the_stream_answers_every_line_and_survives_a_bad_one(sim_obs):
    actor = Actor(packaged("general.pt"))
    lines = io.StringIO(json.dumps(sim_obs.tolist()) + "\n\n[[1, 2]]\nnot json\n" + json.dumps(sim_obs.tolist()) + "\n")
    out = io.StringIO()
    assert stream(actor, lines, out) == 4  # the empty line is skipped
    replies = [json.loads(line) for line in out.getvalue().splitlines()]
    np.testing.assert_allclose(replies[0], actor(sim_obs), atol=1e-6)
    assert "expected observations of shape" in replies[1]["error"] and "error" in replies[2]
    assert replies[3] == replies[0]


def test_act_streams_si_from_the_command_line(replicate, monkeypatch, params, sim_obs):
    units = Units.of(params.world, params.coverage, 30.0, 0.5)
    in_si = from_simulation(sim_obs, load_policy(packaged("general.pt"))[1]["observation_layout"], units)
    monkeypatch.setattr("sys.stdin", io.StringIO(json.dumps(in_si.tolist()) + "\n"))
    code, err = replicate("act", "--policy", str(packaged("general.pt")), "--stream", "--real", "--radius-m", "30",
                          "--speed-ms", "0.5")
    assert code == 0, err
    np.testing.assert_allclose(json.loads(replicate.out), act(packaged("general.pt"), sim_obs), atol=1e-5)
    code, err = replicate("act", "--policy", str(packaged("general.pt")), "--stream", "--radius-m", "30")
    assert code == 2 and "go together, with --real" in err


def test_the_buoy_loop_of_the_deployment_guide_reads_what_the_simulation_does(params, regions, tmp_path):
    """``docs/DEPLOY.md``'s first code block, run as written on a policy exported for 25 m buoys at 1 m/s: its
    observation, built from SI readings (GPS velocity, every other buoy's offset, the shore's uncapped distance
    along each ray), is the simulation's local observation."""
    import re

    from replicate.core.sections import SensorsConfig
    from replicate.world import sensors
    from replicate.world.scenario import general_evaluation_env

    units = Units.of(params.world, params.coverage, 25.0, 1.0)
    export_for(packaged("general.pt"), tmp_path / "buoy.pt", params, units)
    guide = (__import__("pathlib").Path(__file__).parents[2] / "docs" / "DEPLOY.md").read_text()
    block = re.findall(r"```python\n(.*?)```", guide, re.S)[0]
    namespace: dict = {}
    exec(block.replace('"buoy.pt"', repr(str(tmp_path / "buoy.pt"))), namespace)  # noqa: S102 - the guide's code
    meta = load_policy(packaged("general.pt"))[1]
    env, _ = general_evaluation_env(params, regions["bedok"], 9, 1, SensorsConfig(**meta["sensor_config"]), None)
    env.reset(seed=4, start="random")
    rng = np.random.default_rng(4)
    for _ in range(6):
        obs = env.step(rng.uniform(-1, 1, size=(1, 9, 2))).obs[0]
    far = sensors.shore_distances(env.pos, env.shore_edges, env.ray_directions, 1e6)[0]  # uncapped, sim m
    for i in range(9):
        offsets = [tuple(units.length_m(env.pos[0, j] - env.pos[0, i])) for j in range(9) if j != i]
        built = namespace["observation"](units.speed_ms(env.ground_vel[0, i]), offsets, units.length_m(far[i]))
        np.testing.assert_allclose(built, obs[i], rtol=0, atol=1e-5)


def test_a_stray_params_yaml_in_the_working_folder_is_not_read(tmp_path, monkeypatch, capsys):
    """DVC's default file name in a user's folder does not break a command: the installed parameters are read
    unless ``--params`` names a file."""
    from replicate.toolkit.cli import main

    monkeypatch.chdir(tmp_path)
    (tmp_path / "params.yaml").write_text("stages:\n  train: {cmd: python train.py}\n")  # another project's
    argv = ["export", "--policy", str(packaged("general.pt")), "--radius-m", "25", "--speed-ms", "1", "--out"]
    assert main([*argv, "buoy.pt"]) == 0, capsys.readouterr().err
    assert main(["--params", "params.yaml", *argv, "again.pt"]) == 2
    assert "params.yaml" in capsys.readouterr().err and not (tmp_path / "again.pt").exists()


def test_the_onnx_policy_commands_what_the_torchscript_one_does(params, tmp_path, sim_obs):
    """ONNX for runtimes without torch, run by onnxruntime: the same commands for 9 and for 30 buoys, and the
    contract in its metadata."""
    onnxruntime = pytest.importorskip("onnxruntime")
    import onnx

    units = Units.of(params.world, params.coverage, 25.0, 1.0)
    export_for(packaged("general.pt"), tmp_path / "buoy.pt", params, units, tmp_path / "buoy.onnx")
    session = onnxruntime.InferenceSession(str(tmp_path / "buoy.onnx"))
    fleet = np.concatenate([sim_obs, sim_obs, sim_obs, sim_obs[:3]])  # 30 buoys
    for obs in (sim_obs, fleet):
        got = session.run(["action"], {"obs": obs.astype(np.float32)})[0]
        np.testing.assert_allclose(got, act(packaged("general.pt"), obs), atol=1e-5)
    props = {p.key: p.value for p in onnx.load(str(tmp_path / "buoy.onnx")).metadata_props}
    assert json.loads(props["buoy_policy"])["contract"]["si"]["control_period_s"] == pytest.approx(14.1421, abs=1e-4)
