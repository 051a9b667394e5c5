"""The one similarity transform between the simulated world and the water, stated once.

The world is simulated in its own units, the paper's MPE world: lengths in simulation metres (the coverage radius
R is 0.5), time in simulation seconds (a step lasts dt = 0.1), a buoy's velocity relaxing towards its command
(v ← (1 − damping)·v + (F/m)·dt, F = sensitivity·a, each action component in [−1, 1]). Its top speed, the speed a
buoy reaches pushing diagonally for ever, is ``top_speed`` = √2·(F/m)·dt / damping = 2√2 simulation m/s.

A deployment is said in SI: a coverage radius ``radius_m`` (m) and a top speed ``speed_ms`` (m/s, 1.0 for the
paper's BoB buoys). Two numbers map the simulation onto it:

    metres  = radius_m / R                      metres per simulation metre
    seconds = metres · top_speed / speed_ms     seconds per simulation second

so a simulation length ℓ is ℓ·metres m, a duration t is t·seconds s, a speed u is u·metres/seconds m/s. The control
period (one step) is dt·seconds, a drift of c m/s enters the simulation as c·seconds/metres, and an episode of T
steps is a mission of T·dt·seconds. Damping is a share of the velocity per step and the action a share of the
full command, so both are the same numbers in either system: the transform is exact, and every trajectory of the
simulation, times ``metres``, is the trajectory of the same world simulated in metres and seconds
(``si_world``; ``tests/world/test_units.py`` steps both). A trained policy therefore holds for any radius and
speed, as long as its sensors read in simulation units (``observation_units`` says what each column is).

In SI the action's contract reads: the commanded velocity is a·speed_ms/√2 per axis (east, north; m/s), which the
buoy approaches by ``damping`` (25 %) of the gap each control period.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from replicate.core.schema import ConfigError
from replicate.core.sections import CoverageConfig, SensorsConfig, WorldConfig

BOB_SPEED = 1.0  # m/s: the top speed of the paper's buoys (BoB)


def top_speed(world: WorldConfig) -> float:
    """A buoy's top speed through the water, in simulation m/s: the terminal speed of a diagonal push,
    √2·(sensitivity/mass)·dt/damping (infinite without damping)."""
    if world.damping <= 0:
        return math.inf
    return math.sqrt(2.0) * world.sensitivity / world.mass * world.dt / world.damping


@dataclass(frozen=True)
class Units:
    """The similarity transform of one deployment: ``metres`` per simulation metre and ``seconds`` per simulation
    second (module docstring), with the simulation's step ``dt`` (simulation s) for the control period."""

    metres: float
    seconds: float
    dt: float

    @classmethod
    def of(cls, world: WorldConfig, coverage: CoverageConfig, radius_m: float, speed_ms: float = BOB_SPEED) -> Units:
        """The units in which the simulation's coverage radius is ``radius_m`` and its top speed ``speed_ms``."""
        for value, flag, unit in ((radius_m, "radius", "m"), (speed_ms, "speed", "m/s")):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ConfigError(f"the buoys' {flag} must be a positive number of {unit}, got {value!r}")
        metres = radius_m / coverage.radius
        return cls(metres=metres, seconds=metres * top_speed(world) / speed_ms, dt=world.dt)

    # ---- simulation → SI --------------------------------------------------------------------------------
    def length_m(self, sim) -> float | np.ndarray:
        return np.multiply(sim, self.metres)

    def time_s(self, sim) -> float | np.ndarray:
        return np.multiply(sim, self.seconds)

    def speed_ms(self, sim) -> float | np.ndarray:
        return np.multiply(sim, self.metres / self.seconds)

    @property
    def period_s(self) -> float:
        """The control period: one step of the simulation, in seconds."""
        return self.dt * self.seconds

    def steps_time_s(self, steps) -> float | np.ndarray:
        """The time at the end of ``steps`` control periods, in seconds."""
        return np.multiply(steps, self.period_s)

    # ---- SI → simulation --------------------------------------------------------------------------------
    def sim_length(self, metres) -> float | np.ndarray:
        return np.divide(metres, self.metres)

    def sim_speed(self, ms) -> float | np.ndarray:
        return np.multiply(ms, self.seconds / self.metres)

    def steps_for(self, seconds: float) -> int:
        """The control periods a mission of ``seconds`` lasts (at least one, rounded up)."""
        return max(1, math.ceil(seconds / self.period_s - 1e-9))

    def describe(self, world: WorldConfig, coverage: CoverageConfig, sensors: SensorsConfig | None = None) -> dict:
        """The deployment in SI, as every output states it: radius, top speed, control period, the transform, and
        the sensors' ranges in metres."""
        out = {"radius_m": self.length_m(coverage.radius), "top_speed_ms": self.speed_ms(top_speed(world)),
               "control_period_s": self.period_s, "metres_per_sim_m": self.metres,
               "seconds_per_sim_s": self.seconds,
               "action": "commanded velocity a * top_speed_ms / sqrt(2) per axis (east, north), approached by "
                         f"{world.damping:g} of the gap each control period"}
        if sensors is not None:
            out.update(comm_range_m=self.length_m(sensors.comm_range), shore_range_m=self.length_m(sensors.ray_range))
            if sensors.raster:
                out.update(raster_cell_m=self.length_m(2 * sensors.ray_range / sensors.raster))
        return {k: (round(float(v), 9) if isinstance(v, float | np.floating) else v) for k, v in out.items()}


# ---- the same world in SI ------------------------------------------------------------------------------------
def si_world(world: WorldConfig, coverage: CoverageConfig, sensors: SensorsConfig, units: Units
             ) -> tuple[WorldConfig, CoverageConfig, SensorsConfig]:
    """The simulated world's configuration said in metres and seconds: every length × ``metres``, the step ×
    ``seconds``, the force per mass (an acceleration) × metres / seconds². Stepped with a region in metres, it
    moves the buoys exactly as the simulation does, times ``metres``."""
    m, s = units.metres, units.seconds
    world = dataclasses.replace(world, dt=world.dt * s, sensitivity=world.sensitivity * m / s**2,
                                agent_radius=world.agent_radius * m, start_patch=world.start_patch * m,
                                region_area=world.region_area * m**2)
    coverage = dataclasses.replace(coverage, radius=coverage.radius * m, table_spacing=coverage.table_spacing * m,
                                   raster_spacing=coverage.raster_spacing * m)
    sensors = dataclasses.replace(sensors, comm_range=sensors.comm_range * m, ray_range=sensors.ray_range * m,
                                  uncovered=tuple(r * m for r in sensors.uncovered))
    return world, coverage, sensors


# ---- what each observation column is ---------------------------------------------------------------------------
SPEED, LENGTH, PURE = "m/s", "m", "1"


def column_unit(column: str) -> str:
    """The SI unit of a local observation's column (``sensors.columns``): a speed, a length, or a pure number (a
    heard-mask, a share of uncovered water, a cell of the local raster)."""
    if column in ("vx", "vy"):
        return SPEED
    if column.endswith(("_dx", "_dy")) or column.startswith("shore_"):
        return LENGTH
    if column.endswith("_heard") or column.startswith(("uncovered_", "raster_")):
        return PURE
    raise ValueError(f"unknown observation column {column!r}")


def to_simulation(obs: np.ndarray, columns: list[str], units: Units) -> np.ndarray:
    """Local observations read in SI [..., d] → the simulation units a policy reads."""
    factor = np.array([{SPEED: units.sim_speed(1.0), LENGTH: units.sim_length(1.0), PURE: 1.0}[column_unit(c)]
                       for c in columns])
    return np.asarray(obs, dtype=float) * factor


def from_simulation(obs: np.ndarray, columns: list[str], units: Units) -> np.ndarray:
    """Local observations in simulation units [..., d] → SI (``to_simulation``'s inverse)."""
    factor = np.array([{SPEED: units.speed_ms(1.0), LENGTH: units.length_m(1.0), PURE: 1.0}[column_unit(c)]
                       for c in columns])
    return np.asarray(obs, dtype=float) * factor


# ---- the control contract of an exported policy -------------------------------------------------------------
def contract(world: WorldConfig, coverage: CoverageConfig, sensors: SensorsConfig, columns: list[str],
             units: Units | None = None) -> dict:
    """What a buoy's computer needs to run a local-sensor policy: each input column with its unit and meaning, the
    neighbours' order and empty-slot value, the action's meaning, the step; in simulation units, and in SI too
    when ``units`` (the deployment the policy is exported for) are given."""
    meaning = {SPEED: "own velocity over the ground (east, north)", PURE: ""}
    described = []
    for c in columns:
        unit = column_unit(c)
        if c.endswith("_heard"):
            text = "1 if this neighbour slot holds a buoy heard within comm_range, else 0"
        elif c.startswith("uncovered_"):
            text = "share of the points along this ray that are water no buoy heard covers"
        elif c.startswith("raster_water_"):
            text = "1 if the centre of this cell of the map around the buoy (cells east, north) is water, else 0"
        elif c.startswith("raster_covered_"):
            text = "1 if another buoy heard within comm_range covers the centre of this cell (cells east, north)"
        elif c.startswith("shore_"):
            text = "distance to the shore along this compass direction (east = 0 deg, counter-clockwise), " \
                   "capped at shore_range (no shore within reach reads shore_range)"
        elif c.startswith("centroid_"):
            text = "offset to the centroid of the water within shore_range nearer to the buoy than to the " \
                   "neighbours it lists (east, north; 0 for a buoy out of service): computed on board from a " \
                   "chart of the lake's outline"
        elif unit == LENGTH:
            text = "a neighbour's position relative to the buoy (east, north)"
        else:
            text = meaning[unit]
        described.append({"name": c, "unit": unit, "meaning": text})
    v_top = top_speed(world)
    sim = {"control_period": world.dt, "top_speed": v_top, "radius": coverage.radius,
           "comm_range": sensors.comm_range, "shore_range": sensors.ray_range, "damping": world.damping}
    out = {
        "inputs": described,
        "neighbour_order": "nearest first among the buoys heard within comm_range; a slot with no buoy reads "
                           "dx = dy = 0 and heard = 0",
        "action": "a in [-1, 1]^2 per buoy (east, north): a commanded velocity a * top_speed / sqrt(2) per axis, "
                  "which the buoy approaches by `damping` of the gap each control period "
                  "(v <- (1 - damping) v + damping * a * top_speed / sqrt(2))",
        "simulation_units": sim,
        "to_simulation": "length columns / metres_per_sim_m; speed columns * seconds_per_sim_s / metres_per_sim_m; "
                         "pure columns and the action unchanged (world.units)",
    }
    if units is not None:
        out["si"] = units.describe(world, coverage, sensors)
    return out
