"""The actor's networks (``replicate.learn.networks``): the plain MLP, and the CNN that reads a local raster."""

import dataclasses

import torch

from replicate.core import artifacts
from replicate.core.schema import to_dict
from replicate.learn.networks import RasterMLP, observation_net
from replicate.learn.policy import load_policy
from replicate.learn.shared_maddpg import SharedActor
from replicate.toolkit.export import export_general
from replicate.world import sensors
from replicate.world.env import observation_columns


def test_the_plain_observation_keeps_the_mlp_and_a_raster_gets_the_cnn():
    plain = sensors.columns(4, 8)
    assert isinstance(observation_net(plain, len(plain), 16, 2), torch.nn.Sequential)
    columns = sensors.columns(4, 8, raster=7)
    net = observation_net(columns, len(columns), 16, 2)
    assert isinstance(net, RasterMLP) and (net.channels, net.cells) == (2, 7)
    assert net.mlp[0].in_features == len(plain) + net.encoder(torch.zeros(1, 2, 7, 7)).shape[-1]


def test_the_cnn_reads_the_raster_as_an_image():
    """Cell (a, b) of the columns is pixel [b + h, a + h] of the image: a raster with one wet cell east of the buoy
    reaches the encoder as that pixel, and the columns outside the raster reach the MLP unchanged."""
    columns = sensors.columns(1, 4, raster=3)
    net = RasterMLP(columns, 8, 2)
    obs = torch.zeros(len(columns))
    obs[columns.index("raster_water_1_0")] = 1.0
    obs[columns.index("shore_90deg")] = 0.5
    image = obs.index_select(-1, net.raster_index).reshape(2, 3, 3)
    assert image[0, 1, 2] == 1 and image.sum() == 1
    rest = obs.index_select(-1, net.rest_index)
    assert rest.tolist() == [0.5 if c == "shore_90deg" else 0.0 for c in columns if not c.startswith("raster_")]


def test_a_raster_actor_exports_to_the_same_pushes(params, tmp_path):
    """A compass-canonical actor with the raster exports (TorchScript) to the pushes it makes, for any batch
    shape, and its file names the raster among its sensors."""
    sensors_config = dataclasses.replace(params.general.sensors, raster=5)
    columns = observation_columns("local", sensors_config)
    actor = SharedActor(len(columns), 2, 16, "d4_frame", columns)
    artifacts.torch_save(tmp_path / "actor.pt", {
        "format": artifacts.CHECKPOINT_FORMAT, "actor": actor.state_dict(), "observation": "local",
        "sensors": to_dict(sensors_config), "columns": columns, "hidden": 16,
        "learner": to_dict(dataclasses.replace(params.general.learner, hidden=16)), "selected_episode": 0, "seed": 0})
    meta = export_general(tmp_path / "actor.pt", tmp_path / "policy.pt")
    module, _ = load_policy(tmp_path / "policy.pt")
    assert any(s["sensor"] == "local_raster" for s in meta["sensors"])
    obs = torch.rand(3, 7, len(columns))
    with torch.no_grad():
        torch.testing.assert_close(module(obs), actor(obs)[0])
