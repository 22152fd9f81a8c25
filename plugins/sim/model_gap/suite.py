"""The benchmark's suite of hidden-effect cases on a realistic cell (``benchmarks/gap.py``).

Every case is the simulator's ``full`` scenario (:mod:`.simulate`): a UR5e with DH errors of 0.1-0.5 mm
and 0.1-1 mrad on every joint (a new draw per case), a laser tracker 3.5 m away in an unknown frame,
a tool point known to a few centimetres, 200 poses measured while moving over a 3-hour warm-up,
0.05 mm noise per axis. The workflow runs at its defaults (no ``--calibrate``: the full calibration).
Under that geometry:

* **singles**: every non-geometric catalog effect alone at both magnitudes (:data:`.simulate.LEVELS`),
  ``seeds_per_single`` random places / seeds each (places drawn without replacement, cycling):
  ``joint_compliance`` (joints 2, 3), ``backlash`` (joints 1-5) with vgr's ``dir`` convention *and*
  again with the ``dir`` columns counted the other way round, ``encoder_eccentricity`` (joints 1-5),
  ``thermal_drift`` at ``robot`` and ``base``, ``time_latency``, ``depth_bias``;
* **single-link thermal growth**: ``thermal_drift@joint2..5`` at both magnitudes, once growing with
  the warm-up in time (``t_s`` only) and once following a logged motor temperature (``temp_c``);
* **pairs**: every pair of those six effect families at both magnitudes, ``seeds_per_pair`` each (the
  places, a backlash's convention and a thermal drift's place drawn at random, the single-link places
  included);
* **noise-only controls**: the geometry and nothing else;
* **faint singles** (reported apart): every effect at each of its places (thermal growth at ``robot``,
  ``base`` and the four links) at the ``faint`` magnitude, +4 % over the noise: near what 200 poses
  can detect at all, where naming nothing is right and a wrong name is not.

The second round (:func:`robust_suite`, reported apart from the 146 effect cases above):

* **gross outliers**: 1 %, 3 % and 10 % of the rows moved by 1-5 mm (a tracker losing its line of
  sight) on noise-only campaigns, under a joint compliance (high and low), a backlash, a thermal drift
  and a pair;
* **out-of-catalog effects** (simulation only, :mod:`.off_catalog`): joint 6's error following
  ``sin q5`` (the wrist cable), joint 3's following ``sin q2``, joint 5's proportional to ``q4``, a
  twice-per-revolution error of joint 3 and of joint 2, and the wrist cable next to an in-catalog joint
  compliance: nothing (or only the in-catalog effect) has a right name, the right verdict is
  ``unexplained``;
* **40-pose campaigns**: each effect family alone (high), two pairs and noise-only controls.

The geometric catalog effects (a joint zero, a link length, the base frame, the tool offset, a
uniform robot scale, and a range scale once the frame is fitted) are part of every case's geometry:
the default calibration absorbs them, so they are not hidden effects to name.
"""

from __future__ import annotations

from itertools import combinations

import numpy as np

from plugins.sim.model_gap.simulate import LEVELS, SENSOR, HiddenCase, HiddenEffect

#: the effect families hidden under the geometry, and where
PLACES: dict[str, tuple[str, ...]] = {
    "joint_compliance": ("joint2", "joint3"),
    "backlash": ("joint1", "joint2", "joint3", "joint4", "joint5"),
    "encoder_eccentricity": ("joint1", "joint2", "joint3", "joint4", "joint5"),
    "thermal_drift": ("robot", "base"),
    "time_latency": (SENSOR,),
    "depth_bias": (SENSOR,),
}
LINKS = ("joint2", "joint3", "joint4", "joint5")  # the single-link thermal growth's places
PAIR_THERMAL_PLACES = ("robot", "base", *LINKS)
N_POSES = 200


def suite(
    full: bool = True, seed: int = 0, seeds_per_single: int = 5, seeds_per_pair: int = 2, noise_controls: int = 30
) -> list[HiddenCase]:
    """The cases of the module docstring; ``full=False``: a small subset for a quick look."""
    rng = np.random.default_rng(seed)
    cases: list[HiddenCase] = []
    reps = seeds_per_single if full else 1
    levels = ("low", "high")

    def add(case_id: str, kind: str, level: str, effects: tuple[HiddenEffect, ...], **kw) -> None:
        cases.append(HiddenCase(case_id, kind, level, "full", effects, int(rng.integers(1 << 31)), N_POSES, **kw))

    for name, places in PLACES.items():
        for flip in (False, True) if name == "backlash" else (False,):
            for level in levels if full else ("high",):
                order = [str(w) for w in rng.permutation(places)]
                for r in range(reps):
                    where = order[r % len(order)]
                    tag = "-flipdir" if flip else ""
                    add(f"{name}@{where}-{level}-{r}{tag}", "single", level,
                        (HiddenEffect(name, where, LEVELS[level]),), flip_dir=flip)  # fmt: skip
    for temperature in (False, True):
        for level in levels if full else ("high",):
            for where in LINKS if full else LINKS[:1]:
                tag = "-temp" if temperature else ""
                add(f"thermal_drift@{where}-{level}{tag}", "single", level,
                    (HiddenEffect("thermal_drift", where, LEVELS[level]),), temperature=temperature)  # fmt: skip
    pairs = (
        list(combinations(PLACES, 2)) if full else [("joint_compliance", "backlash"), ("thermal_drift", "depth_bias")]
    )
    for a, b, r in ((a, b, r) for a, b in pairs for r in range(seeds_per_pair if full else 1)):
        for level in levels if full else ("high",):
            where = [str(rng.choice(PAIR_THERMAL_PLACES if n == "thermal_drift" else PLACES[n])) for n in (a, b)]
            flip = bool(rng.integers(2)) if "backlash" in (a, b) else False
            effs = tuple(HiddenEffect(n, w, LEVELS[level]) for n, w in zip((a, b), where, strict=True))
            tag = "-flipdir" if flip else ""
            add(f"{a}@{where[0]}+{b}@{where[1]}-{level}-{r}{tag}", "pair", level, effs, flip_dir=flip)
    for i in range(noise_controls if full else 4):
        add(f"noise-{i}", "noise", "none", (), temperature=bool(i % 4 == 3))
    if full:
        for name, places in PLACES.items():
            for where in (*places, *LINKS) if name == "thermal_drift" else places:
                add(f"{name}@{where}-faint", "single", "faint", (HiddenEffect(name, where, LEVELS["faint"]),))
    return cases


#: gross-error fractions of the robust suite (of the rows)
OUTLIER_FRACTIONS = (0.01, 0.03, 0.10)
SMALL_POSES = 40


def robust_suite(seed: int = 1, full: bool = True) -> list[HiddenCase]:
    """The second round's cases (module docstring); ``full=False``: one of each group."""
    rng = np.random.default_rng(seed)
    cases: list[HiddenCase] = []

    def add(case_id: str, kind: str, level: str, effects: tuple[HiddenEffect, ...], **kw) -> None:
        n = kw.pop("n_samples", N_POSES)
        cases.append(HiddenCase(case_id, kind, level, "full", effects, int(rng.integers(1 << 31)), n, **kw))

    def eff(name: str, where: str, level: str) -> HiddenEffect:
        return HiddenEffect(name, where, LEVELS[level])

    hidden = [
        ("noise", "none", ()),
        ("noise", "none", ()),
        ("noise", "none", ()),
        ("single", "high", (eff("joint_compliance", "joint2", "high"),)),
        ("single", "high", (eff("joint_compliance", "joint3", "high"),)),
        ("single", "low", (eff("joint_compliance", "joint2", "low"),)),
        ("single", "high", (eff("backlash", "joint3", "high"),)),
        ("single", "high", (eff("thermal_drift", "robot", "high"),)),
        ("pair", "high", (eff("joint_compliance", "joint2", "high"), eff("depth_bias", SENSOR, "high"))),
    ]
    for frac in OUTLIER_FRACTIONS if full else OUTLIER_FRACTIONS[1:2]:
        for i, (kind, level, effects) in enumerate(hidden if full else hidden[2:4]):
            label = "+".join(f"{e.name}@{e.where}" for e in effects) or "noise"
            n_out = round(frac * N_POSES)
            add(f"outliers{frac:.0%}-{label}-{level}-{i}", f"outlier_{kind}", level, effects, outliers=n_out)
    off = [
        ("high", (eff("cross_joint_sin", "joint6~q5", "high"),)),
        ("high", (eff("cross_joint_sin", "joint6~q5", "high"),)),
        ("low", (eff("cross_joint_sin", "joint6~q5", "low"),)),
        ("high", (eff("cross_joint_sin", "joint3~q2", "high"),)),
        ("high", (eff("cross_joint_linear", "joint5~q4", "high"),)),
        ("low", (eff("cross_joint_linear", "joint5~q4", "low"),)),
        ("high", (eff("second_harmonic", "joint3", "high"),)),
        ("high", (eff("second_harmonic", "joint2", "high"),)),
        ("high", (eff("cross_joint_sin", "joint6~q5", "high"), eff("joint_compliance", "joint2", "high"))),
        ("high", (eff("cross_joint_sin", "joint6~q5", "high"), eff("joint_compliance", "joint2", "high"))),
    ]
    for i, (level, effects) in enumerate(off if full else off[:1]):
        label = "+".join(f"{e.name}@{e.where}" for e in effects)
        add(f"offcatalog-{label}-{level}-{i}", "off_catalog", level, effects)
    small: list[tuple[str, str, tuple[HiddenEffect, ...]]] = [
        ("single", "high", (eff(name, str(rng.choice(places)), "high"),)) for name, places in PLACES.items()
    ]
    small += [
        ("pair", "high", (eff("joint_compliance", "joint2", "high"), eff("backlash", "joint3", "high"))),
        ("pair", "high", (eff("thermal_drift", "robot", "high"), eff("depth_bias", SENSOR, "high"))),
    ]
    small += [("noise", "none", ())] * 4
    for i, (kind, level, effects) in enumerate(small if full else small[:1] + small[-1:]):
        label = "+".join(f"{e.name}@{e.where}" for e in effects) or "noise"
        add(f"poses{SMALL_POSES}-{label}-{i}", f"small_{kind}", level, effects, n_samples=SMALL_POSES)
    return cases
