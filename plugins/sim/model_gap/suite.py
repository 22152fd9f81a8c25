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
