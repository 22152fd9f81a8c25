"""Hidden-effect datasets from the simulated cell, for the model-gap tests and benchmark.

A measurement campaign on the simulated cell: the simulated controller
(:class:`plugins.sim.controller.SimRobotController`) drives the *true* robot (nominal model + hidden
robot effects, :class:`RobotWithEffects`) through joint moves to random configurations, with a
random payload per move, from a cold start over three hours with samples denser during the warm-up
(sample *i* of *n* near ``3 h (i / n)^2``: half of them in the first 45 minutes).
A ranging sensor ("camera": a 3-D camera or laser tracker) 1.6 m away measures the tool point while
the robot moves, with its hidden measurement effects (stream latency: the reading at ``t`` shows the
truth at ``t - L``, the tracker's law; range scale / bias: the depth camera's law) and isotropic
Gaussian noise. The dataset carries what a real campaign logs: commanded joints, joint velocities,
approach directions, time, payload, range. The hidden effects are known only to the caller.

Scenarios: ``full`` (a real cell: the robot has a realistic set of geometric errors -- DH errors of
0.1-0.5 mm and 0.1-1 mrad on every joint --, the tracker stands metres away in an unknown frame, the
tool point is only roughly known; the workflow's default baseline calibrates all of it), ``tracker``
(the nominal geometry, the sensor's pose and the tool point unknown: the workflow calibrates ``frame``
and ``tool``) and ``known`` (both known, e.g. a registered sensor frame and a measured TCP: nothing is
calibrated, so a base or tool error is observable at all). A case can log the approach directions
the other way round (``flip_dir``: +1 after moving towards smaller angles, as some controllers do)
and a temperature (``temperature``: a ``temp_c`` column that rises as the motors warm up; a single
link's thermal growth then follows it linearly), and measure several reflectors at every pose
(``points``: one row per pose and reflector, named in a ``point`` column; :data:`REFLECTORS`).

Out-of-catalog effects and gross errors (simulation only, :mod:`.off_catalog`): a hidden effect may be
one vgr's catalog lacks (a joint error driven by another joint's angle, a twice-per-revolution
error), which no right answer names; a case can add gross errors to a few rows (``outliers``: a
tracker losing its line of sight, 1-5 mm) and measure some poses again (``replicates``: each of the
first poses measured twice more, back to back), from their own random stream, so the rest of the
campaign is the same as without them.

The benchmark's suite of cases is :func:`.suite.suite`. :attr:`SimulatedCampaign.gap_m` is the gap all hidden
effects leave together (two can partly cancel); the campaign also carries the truth (noise-free
displacement of each hidden effect, the calibration's span, the true frames) from which
:mod:`.detectability` classifies a case a priori, without the measurements.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from engine.transforms import inv
from plugins.calibration.kinematics import KinematicSamples
from plugins.model_gap.data import GapData
from plugins.model_gap.effects import _link_lengths, uniform_scale_offsets
from plugins.robot import effects as fx
from plugins.robot.effects import RobotEffect, SampleContext
from plugins.robot.effects.measurement import apply_range_distortion
from plugins.robot.kinematics import RobotModel
from plugins.robot.model_file import load_robot_model
from plugins.robot.with_effects import RobotWithEffects
from plugins.sim.camera import look_at
from plugins.sim.clock import SimClock
from plugins.sim.controller import SimRobotController
from plugins.sim.model_gap.off_catalog import OFF_CATALOG, add_gross_errors, unit_effect
from plugins.sim.sensor_effects import CameraEffects, TrackerEffects

NOISE_M = 5e-5  # 0.05 mm per axis (laser-tracker class)
SENSOR = "camera"
T_WORLD_SENSOR = look_at((1.3, -0.9, 0.9), (0.0, 0.0, 0.25))
T_WORLD_TRACKER_FAR = look_at((2.7, -1.9, 1.3), (0.0, 0.0, 0.3))  # the ``full`` scenario: 3.5 m away
DH_LENGTH_ERROR_M = (1e-4, 5e-4)  # the ``full`` scenario's geometric errors: magnitude ranges, random sign
DH_ANGLE_ERROR_RAD = (1e-4, 1e-3)
TOOL_TRUE = (0.03, -0.02, 0.12)  # measured point on the flange (m)
TOOL_GUESS = (0.0, 0.0, 0.1)  # what the user's model says in the tracker scenario
# reflectors on the tool (TCP frame, m) of a campaign measuring several points per pose: R1 is the TCP
REFLECTORS = ((0.0, 0.0, 0.0), (0.05, 0.0, 0.0), (0.0, 0.04, 0.02))
CAMPAIGN_S = 3 * 3600.0

# Hidden magnitudes: the RMS (3-D, over the campaign) of the part of the effect's displacement of the
# measured point that the scenario's baseline calibration cannot absorb -- the gap the effect leaves.
# Noise alone gives a 3-D RMS of sqrt(3) x 0.05 = 0.087 mm: "low" raises the RMS by 15 %, "high" doubles it;
# "faint" (+4 %) is near what 200 poses can detect at all (the benchmark reports it apart).
LEVELS: dict[str, float] = {"faint": 25e-6, "low": 50e-6, "high": 150e-6}
# the two uniform scales (a range scale of the sensor, a uniform scale of the robot) are exactly
# confounded once the frame is fitted and separable with known frames
BOTH_SCENARIOS = ("depth_scale", "robot_scale")
KNOWN_FRAME_EFFECTS = ("base_frame", "tool_offset")
# the baseline calibration of each scenario; None: the workflow's default (the full calibration)
SCENARIO_CALIBRATION: dict[str, tuple[str, ...] | None] = {"tracker": ("frame", "tool"), "known": (), "full": None}


@dataclass(frozen=True)
class HiddenEffect:
    name: str
    where: str
    gap_m: float  # RMS gap the effect leaves after the baseline calibration (m), see LEVELS
    # the effect's sign (scalar effects: ``(+1,)`` / ``(-1,)``) or direction (``tool_offset``: a 3-vector in
    # the flange frame) instead of a random one; None (the suite): random. For tests that build a case
    # with a known geometry (two effects that cancel, a tool offset along a chosen axis)
    direction: tuple[float, ...] | None = None


@dataclass(frozen=True)
class HiddenCase:
    case_id: str
    kind: str  # single | pair | noise
    level: str  # low | high | none
    scenario: str  # tracker | known
    effects: tuple[HiddenEffect, ...]
    seed: int
    n_samples: int = 200
    noise_m: float = NOISE_M
    flip_dir: bool = False  # the data's dir columns count the approach direction the other way round
    temperature: bool = False  # the data log a temp_c column (a link's thermal growth follows it)
    points: int = 1  # reflectors measured at every pose (REFLECTORS; one row each, a point column)
    outliers: int = 0  # rows with a gross error (off_catalog.add_gross_errors)
    outlier_m: tuple[float, float] = (1e-3, 5e-3)  # their size range (m)
    replicates: int = 0  # the first poses measured twice more each (single point only)

    @property
    def off_catalog(self) -> list[str]:
        """The hidden effects vgr's catalog does not have (simulation only): none of them has a right name."""
        return [f"{e.name}@{e.where}" for e in self.effects if e.name in OFF_CATALOG]

    @property
    def calibrate(self) -> tuple[str, ...] | None:
        """The baseline calibration ``vgr gap`` is given (None: its default, the full calibration)."""
        return SCENARIO_CALIBRATION[self.scenario]

    @property
    def expected(self) -> set[tuple[str, str]]:
        """The hidden effects the workflow should name (the out-of-catalog ones have no name)."""
        return {(e.name, e.where) for e in self.effects if e.name not in OFF_CATALOG}


@dataclass
class SimulatedCampaign:
    data: GapData
    model: RobotModel  # the nominal model the user gives to `vgr gap`
    truth: RobotWithEffects
    camera: CameraEffects
    tracker: TrackerEffects
    # 3-D RMS of the part of *all* hidden effects together that the baseline calibration cannot absorb
    # (noise-free, m): each effect alone leaves its ``gap_m``, but two effects can partly cancel
    gap_m: float = 0.0
    # The truth, for the a-priori analysis (:mod:`.detectability`), never shown to the workflow:
    # noise-free displacement ``(N, 3)`` (m, measurement frame) of the measured point by each hidden
    # effect alone and by all of them together (not calibrated: the calibration's span is ``calibration_m``)
    signals_m: tuple[np.ndarray, ...] = ()
    signal_m: np.ndarray | None = None
    calibration_m: np.ndarray | None = None  # (3N, k) position columns of the scenario's baseline calibration
    truth_model: RobotModel | None = None  # true geometry (``full``: with its errors), sensor frame, tool
    truth_data: GapData | None = None  # the campaign's inputs with noise-free, effect-free measurements
    outlier_rows: np.ndarray | None = None  # rows of ``data`` given a gross error (ascending)


def _random_unit(rng: np.random.Generator, n: int = 3) -> np.ndarray:
    v = rng.normal(size=n)
    return v / np.linalg.norm(v)


def _unit_effect(
    e: HiddenEffect, model: RobotModel, rng: np.random.Generator, temperature: bool = False
) -> tuple[RobotEffect | None, dict]:
    """The hidden effect at a unit-ish size with a random sign / direction / phase (scaled later)."""
    sign = float(rng.choice((-1.0, 1.0)))
    if e.direction is not None and e.name != "tool_offset":
        if e.name not in _SIGNED or len(e.direction) != 1:
            raise ValueError(f"{e.name}: give the sign of a scalar effect ({', '.join(_SIGNED)}) or a tool direction")
        sign = float(np.sign(e.direction[0]))
    if e.name in OFF_CATALOG:  # simulation only: effects vgr's catalog does not have
        return unit_effect(e.name, e.where, rng), {}
    j = int(e.where[5:]) if e.where.startswith("joint") else 0
    u = 1e-4
    if e.name == "joint_offset":
        return fx.JointOffset((j,), (sign * u,)), {}
    if e.name == "link_length":
        return fx.LinkLength((j,), (sign * u,)), {}
    if e.name == "joint_compliance":
        return fx.JointCompliance((j,), (1e-6,)), {}
    if e.name == "backlash":
        return fx.Backlash((j,), (u,)), {}
    if e.name == "encoder_eccentricity":
        phase = rng.uniform(0, 2 * np.pi)
        return fx.EncoderEccentricity((j,), (u * np.cos(phase),), (u * np.sin(phase),)), {}
    if e.name == "thermal_drift" and e.where == "base":  # the pedestal / table grows
        return fx.ThermalDrift(("base.tz",), (sign * u,), 1800.0), {}
    if e.name == "thermal_drift" and j:  # one link grows: with the logged temperature, else in time
        name = next(n for jj, n, _ in _link_lengths(model) if jj == j)
        if temperature:
            return fx.TemperatureExpansion((name,), (sign * u,), 20.0), {}
        return fx.ThermalDrift((name,), (sign * u,), 1800.0), {}
    if e.name == "thermal_drift":
        return fx.ThermalDrift.linear_expansion(model, 1.0, expansion_per_k=sign * u, time_constant_s=1800.0), {}
    if e.name == "robot_scale":  # every length and the tool point of the true robot times 1 + s
        offsets = uniform_scale_offsets(model)
        return fx.GeometricErrors(tuple(offsets), tuple(sign * u * v for v in offsets.values())), {}
    if e.name == "base_frame":
        return fx.BaseFrameError(
            offsets=tuple(np.concatenate([u * _random_unit(rng), u * _random_unit(rng)]).tolist())
        ), {}
    if e.name == "tool_offset":
        d = _random_unit(rng) if e.direction is None else np.asarray(e.direction, float) / np.linalg.norm(e.direction)
        return fx.ToolOffsetError(("tx", "ty", "tz"), tuple((u * d).tolist())), {}
    if e.name == "time_latency":  # the measurement stream lags the joint stream
        return None, {e.name: 1e-3}
    if e.name in _MEASUREMENT:
        return None, {e.name: sign * u}
    raise ValueError(f"unknown effect {e.name!r}")


_SIGNED = ("joint_offset", "link_length", "thermal_drift", "depth_scale", "depth_bias", "robot_scale")


def _scaled(effect: RobotEffect, factor: float) -> RobotEffect:
    """The effect ``factor`` times larger (a thermal drift's time constant is a shape, not a size)."""
    x = effect.pack() * factor
    if isinstance(effect, fx.ThermalDrift):
        x[-1] = effect.time_constant_s
    return effect.unpack(x)


def simulate_campaign(
    effects: tuple[HiddenEffect, ...],
    *,
    scenario: str = "tracker",
    n_samples: int = 200,
    noise_m: float = NOISE_M,
    seed: int = 0,
    robot: str = "ur5e",
    flip_dir: bool = False,
    temperature: bool = False,
    points: int = 1,
    outliers: int = 0,
    outlier_m: tuple[float, float] = (1e-3, 5e-3),
    replicates: int = 0,
) -> SimulatedCampaign:
    """Run a measurement campaign on the simulated cell with the given hidden effects."""
    if scenario not in SCENARIO_CALIBRATION:
        raise ValueError(f"unknown scenario {scenario!r}")
    rng = np.random.default_rng(seed)
    nominal = load_robot_model(robot)
    T_meas_world = inv(T_WORLD_TRACKER_FAR if scenario == "full" else T_WORLD_SENSOR)
    true_model = nominal.with_tool(_translation(TOOL_TRUE))
    if scenario == "full":  # a real robot: geometric errors on every joint (their own seed stream)
        true_model = true_model.with_param_offsets(geometric_errors(nominal, np.random.default_rng([seed, 2])))

    # 1. the motion: the controller plans it (the effects do not change what it commands)
    mo = _move(true_model, nominal, n_samples, rng)
    Q, QD, T_s, PAY = mo.Q, mo.QD, mo.T_s, mo.PAY
    TEMP = motor_temperature(T_s, np.random.default_rng([seed, 3])) if temperature else None
    ctx = SampleContext(t_s=T_s, direction=np.array(mo.d), payload_kg=PAY, temp_c=TEMP)

    # 2. every hidden effect scaled so that the gap it leaves after the calibration has the RMS asked
    measured = _Measurement(true_model, Q, QD, ctx, T_meas_world)
    base = measured([], {})
    C = _calibration_columns(true_model, Q, T_meas_world, scenario)
    robot_effects, meas, signals = _hide(effects, measured, base, C, rng, temperature)
    truth = RobotWithEffects(true_model, robot_effects)
    signal = measured(robot_effects, meas) - base
    combined_gap = _rms_3d(_uncalibrated(signal, C))
    latency = meas.get("time_latency", 0.0)
    camera = CameraEffects(depth_scale=1.0 + meas.get("depth_scale", 0.0), depth_bias_m=meas.get("depth_bias", 0.0))
    tracker = TrackerEffects(latency_s=latency)

    # 3. what the sensor reports: the truth at t - L (the controller's state then), ranged, noisy
    logged_dir = -np.array(mo.d) if flip_dir else np.array(mo.d)  # what the controller logs
    data = _sensor_data(
        mo, truth, camera, latency, T_meas_world, TEMP, logged_dir, points=points, noise_m=noise_m, rng=rng,
        replicates=(replicates, np.random.default_rng([seed, 6])),
    )  # fmt: skip
    moved, rows = add_gross_errors(data.samples.positions, outliers, outlier_m, np.random.default_rng([seed, 5]))
    if outliers:
        data.samples.positions = moved
        data.range_m = np.linalg.norm(moved, axis=1)
    # the true frames (the sensor frame as the model's world: so is its gravity vector)
    known = _with_gravity(true_model.with_base(T_meas_world), T_meas_world[:3, :3] @ nominal.gravity_world)
    model = known if scenario == "known" else nominal.with_tool(_translation(TOOL_GUESS))
    clean = KinematicSamples(Q, base, None, T_s, logged_dir, TEMP, PAY)
    truth_data = GapData(clean, qd=QD, range_m=np.linalg.norm(base, axis=1), sensor=SENSOR, source="simulated truth")
    return SimulatedCampaign(
        data, model, truth, camera, tracker, combined_gap, tuple(signals), signal, C, known, truth_data, rows
    )


@dataclass(eq=False)
class _Motion:
    """The campaign's poses as the controller drove them: the controller (its state at any time), and per
    sample the joints, joint velocities, approach directions (one array per sample), time and payload."""

    ctl: SimRobotController
    Q: np.ndarray
    QD: np.ndarray
    d: list[np.ndarray]
    T_s: np.ndarray
    PAY: np.ndarray


def _move(true_model: RobotModel, nominal: RobotModel, n_samples: int, rng: np.random.Generator) -> _Motion:
    """Step 1: joint moves to random configurations within the limits (at most +-pi), a random payload
    and speed per move, one sample at a random time of each move; from a cold start, the i-th sample
    near ``CAMPAIGN_S (i / n)^2``."""
    clock = SimClock()
    ctl = SimRobotController(
        true_model, clock, warmup_start_s=0.0, keep_moves=max(2, n_samples)
    )  # all: read back below
    lo, hi = np.maximum(nominal.lower, -np.pi), np.minimum(nominal.upper, np.pi)
    q, qd, d, t, pay = [], [], [], [], []
    for i in range(n_samples):
        ctl.set_payload(float(rng.choice((0.0, 2.5))))
        target = lo + rng.random(nominal.dof) * (hi - lo)
        res = ctl.move_j(f"m{i}", target, speed=float(rng.uniform(0.5, 1.05)), accel=1.4)
        if not res.accepted:
            raise RuntimeError(f"simulated move refused: {res.reason}")
        t_meas = res.start_s + rng.uniform(0.2, 0.8) * res.duration_s
        st = ctl.state(t_meas)
        q.append(st.q)
        qd.append(st.qd)
        d.append(st.approach_direction)
        t.append(t_meas)
        pay.append(ctl.payload_kg)
        # from a cold start, measured densely during the warm-up: the i-th sample near T (i / n)^2
        clock.advance_to(max(res.end_s, CAMPAIGN_S * ((i + 1) / n_samples) ** 2))
    return _Motion(ctl, np.array(q), np.array(qd), d, np.array(t), np.array(pay))


@dataclass(eq=False)
class _Measurement:
    """The noise-free measurement of the campaign's poses by the true robot with some hidden effects:
    the tool point in the measurement frame, with the stream latency and the range distortion."""

    true_model: RobotModel
    Q: np.ndarray
    QD: np.ndarray
    ctx: SampleContext
    T_meas_world: np.ndarray

    def __call__(self, robot_effects: list[RobotEffect], meas: dict[str, float]) -> np.ndarray:
        lat = meas.get("time_latency", 0.0)
        p_w = RobotWithEffects(self.true_model, robot_effects).fk(self.Q - lat * self.QD, self.ctx)[:, :3, 3]
        p = p_w @ self.T_meas_world[:3, :3].T + self.T_meas_world[:3, 3]
        return apply_range_distortion(p, meas.get("depth_scale", 0.0), meas.get("depth_bias", 0.0))


def _uncalibrated(disp: np.ndarray, C: np.ndarray) -> np.ndarray:
    """``(N, 3)`` displacement less what the baseline calibration's columns ``C`` absorb (least squares)."""
    if C.shape[1]:
        disp = disp - (C @ np.linalg.lstsq(C, disp.reshape(-1), rcond=None)[0]).reshape(disp.shape)
    return disp


def _rms_3d(disp: np.ndarray) -> float:
    """3-D RMS over the samples of an ``(N, 3)`` displacement."""
    return float(np.sqrt(np.mean(np.sum(disp**2, axis=1))))


def _hide(
    effects: tuple[HiddenEffect, ...],
    measured: _Measurement,
    base: np.ndarray,
    C: np.ndarray,
    rng: np.random.Generator,
    temperature: bool,
) -> tuple[list[RobotEffect], dict[str, float], list[np.ndarray]]:
    """Step 2: each hidden effect at a unit size (:func:`_unit_effect`), scaled so that the gap it leaves
    after the calibration has the RMS ``gap_m``: (the robot effects, the measurement effects, the
    noise-free displacement of the measured point by each effect alone)."""
    robot_effects: list[RobotEffect] = []
    meas: dict[str, float] = {}
    signals: list[np.ndarray] = []
    for e in effects:
        # on the true model: its tool point is the true one (robot_scale scales it)
        unit, unit_meas = _unit_effect(e, measured.true_model, rng, temperature)
        disp = _uncalibrated(measured([unit] if unit else [], unit_meas) - base, C)
        factor = e.gap_m / _rms_3d(disp)
        scaled = [_scaled(unit, factor)] if unit is not None else []
        scaled_meas = {k: v * factor for k, v in unit_meas.items()}
        robot_effects += scaled
        meas.update(scaled_meas)
        signals.append(measured(scaled, scaled_meas) - base)
    return robot_effects, meas, signals


def _sensor_data(
    mo: _Motion,
    truth: RobotWithEffects,
    camera: CameraEffects,
    latency: float,
    T_meas_world: np.ndarray,
    TEMP: np.ndarray | None,
    logged_dir: np.ndarray,
    *,
    points: int,
    noise_m: float,
    rng: np.random.Generator,
    replicates: tuple[int, np.random.Generator] = (0, np.random.default_rng(0)),
) -> GapData:
    """Step 3: what the campaign logs: per pose and reflector (one row each) the sensor's reading -- the
    true robot at ``t - L`` (the controller's state then), ranged, noisy -- and the controller's logs."""
    Q, T_s, PAY = mo.Q, mo.T_s, mo.PAY
    seen = [mo.ctl.state(ti - latency) for ti in T_s]
    ctx_seen = SampleContext(
        t_s=T_s - latency, direction=np.array([s_.approach_direction for s_ in seen]), payload_kg=PAY, temp_c=TEMP
    )
    T_seen = truth.fk(np.array([s_.q for s_ in seen]), ctx_seen)
    k = len(REFLECTORS[:points]) if points > 1 else 1  # several reflectors: one row per pose and reflector
    rows = np.repeat(np.arange(len(Q)), k)
    refl = np.array(REFLECTORS[:k])[np.tile(np.arange(k), len(Q))]
    p_world = np.einsum("nij,nj->ni", T_seen[rows, :3, :3], refl) + T_seen[rows, :3, 3]
    p_true = p_world @ T_meas_world[:3, :3].T + T_meas_world[:3, 3]
    p = apply_range_distortion(p_true, camera.depth_scale - 1.0, camera.depth_bias_m)
    p = p + rng.normal(0.0, noise_m, p.shape)
    n_rep, rep_rng = replicates
    if n_rep:  # the first poses measured twice more, back to back: the same reading, fresh noise
        if k > 1:
            raise ValueError("replicates need a single measured point per pose")
        again = np.repeat(np.arange(min(n_rep, len(Q))), 2)
        clean = apply_range_distortion(p_true[again], camera.depth_scale - 1.0, camera.depth_bias_m)
        p = np.concatenate([p, clean + rep_rng.normal(0.0, noise_m, clean.shape)])
        rows = np.concatenate([rows, again])
    names = np.array([f"R{i + 1}" for i in range(k)])[np.tile(np.arange(k), len(Q))] if k > 1 else None
    temp = None if TEMP is None else TEMP[rows]
    samples = KinematicSamples(Q[rows], p, None, T_s[rows], logged_dir[rows], temp, PAY[rows], names)
    return GapData(samples, qd=mo.QD[rows], range_m=np.linalg.norm(p, axis=1), sensor=SENSOR, source="simulated")


def geometric_errors(model: RobotModel, rng: np.random.Generator) -> dict[str, float]:
    """A realistic set of geometric errors: every joint's DH ``theta d a alpha`` off by 0.1-1 mrad or
    0.1-0.5 mm (uniform magnitude, random sign): what a robot's manufacturing and assembly leave."""
    out = {}
    for j in range(1, model.dof + 1):
        for k in ("theta", "d", "a", "alpha"):
            lo, hi = DH_ANGLE_ERROR_RAD if k in ("theta", "alpha") else DH_LENGTH_ERROR_M
            out[f"joint{j}.{k}"] = float(rng.choice((-1.0, 1.0)) * rng.uniform(lo, hi))
    return out


def motor_temperature(t_s: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A logged motor temperature (deg C) over a warm-up: 20 deg C rising by 9 K with a 40 min time
    constant, a 0.6 K oscillation of the cell's air conditioning (28 min period), 0.05 K sensor noise."""
    t = np.asarray(t_s, dtype=float)
    return (
        20.0 + 9.0 * (1.0 - np.exp(-t / 2400.0)) + 0.6 * np.sin(2 * np.pi * t / 1680.0) + rng.normal(0, 0.05, t.shape)
    )


def _calibration_columns(model: RobotModel, Q: np.ndarray, T_meas_world: np.ndarray, scenario: str) -> np.ndarray:
    """Position columns ``(3N, k)`` of what the scenario's baseline calibration fits (frame, tool point;
    the ``full`` scenario every joint parameter too: the span is what matters, redundant columns do not)."""
    levels = SCENARIO_CALIBRATION[scenario]
    if levels is not None and not levels:
        return np.zeros((3 * len(Q), 0))
    names = [f"base.{c}" for c in ("tx", "ty", "tz", "rx", "ry", "rz")] + [f"tool.{c}" for c in ("tx", "ty", "tz")]
    if levels is None:
        names += [n for n in model.param_names if n.startswith("joint")]
    m = model.with_base(T_meas_world)
    _, J = m.param_jacobian(Q)
    return J[:, :3, [m.chain.index(n) for n in names]].reshape(3 * len(Q), -1)


_MEASUREMENT = ("time_latency", "depth_scale", "depth_bias")


def _with_gravity(model: RobotModel, g: np.ndarray) -> RobotModel:
    return RobotModel(model.name, model.convention, model.chain, model.joints, links=model.links, gravity_world=g,
                      description=model.description, sources=model.sources, home=model.home)  # fmt: skip


def _translation(xyz) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = xyz
    return T


def make_case(case: HiddenCase) -> SimulatedCampaign:
    return simulate_campaign(
        case.effects,
        scenario=case.scenario,
        n_samples=case.n_samples,
        noise_m=case.noise_m,
        seed=case.seed,
        flip_dir=case.flip_dir,
        temperature=case.temperature,
        points=case.points,
        outliers=case.outliers,
        outlier_m=case.outlier_m,
        replicates=case.replicates,
    )
