"""Tolerance (Monte Carlo) studies: which plant parameters vary, how, and the samples drawn.

``--vary PARAM=SPREAD`` (repeatable), one grammar (:func:`parse_vary`)::

    SPREAD := [DIST ":"] ["±" | "+-"] NUMBER ["%"]
    DIST   := "uniform" (default) | "normal"

``coulomb=±20%`` — uniform within ±20 % of the nominal value; ``tach_brush_drop=normal:30%`` —
normal, σ = 30 % of nominal, truncated at ±3σ (redrawn beyond); ``inertia=uniform:0.5`` —
absolute, in the parameter's SI unit (±0.5 kg·m²). A spread of 0 draws the nominal value itself.

Each parameter perturbs the EMULATED plant or rig electronics of the analysed joint only (the
plant tables of the rig file, see :data:`PARAMETERS`), never ``[joint.servo.nominal]``: the
controller keeps believing the rig file's nominal values (servo.nominal), as a real controller
would. Nominal values are the plant's as the rig file gives them (or the plant model's default).

Samples (:func:`draw_samples`) are drawn in the client, one generator per sample seeded with
``(seed, sample)``, so sample k has the same values whatever the engine or the number of samples,
and they travel with each task as plain numbers.
"""

from __future__ import annotations

import copy
import math
import re
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

from vmehil.errors import VmehilError

TRUNCATE_SIGMA = 3.0  #: a normal spread is truncated at ±3σ (redrawn beyond), so its extremes are known


class VaryError(VmehilError, ValueError):
    """A malformed ``--vary`` spread, an unknown parameter, or a spread leaving its range."""


@dataclass(frozen=True)
class Parameter:
    """A plant/rig value a study may vary: ``section``/``key`` in the joint's ``[[joint]]`` table
    (``section`` "crate.adc": every ADC board's key), the row ``column`` it is reported in, and its
    range (``lower``, included unless ``lower_open``; ``upper`` excluded)."""

    name: str
    section: str
    key: str
    column: str
    what: str
    lower: float = 0.0
    lower_open: bool = False
    upper: float = math.inf


PARAMETERS: dict[str, Parameter] = {p.name: p for p in (
    Parameter("coulomb", "friction", "coulomb_nm", "plant_coulomb_nm",
              "Coulomb friction at the motor shaft, N·m (the breakout level scales with it)"),
    Parameter("viscous", "friction", "viscous_nm_s_per_rad", "plant_viscous_nm_s_per_rad",
              "viscous friction at the motor shaft, N·m·s/rad"),
    Parameter("ripple", "friction", "ripple_fraction", "plant_ripple_fraction",
              "Harmonic Drive friction ripple fraction (0 ≤ m < 1)", upper=1.0),
    Parameter("tach_brush_drop", "tach", "brush_drop_v", "plant_tach_brush_drop_v",
              "tachometer brush drop, V (the velocity dead band is drop/gradient)"),
    Parameter("inertia", "link", "inertia_kg_m2", "plant_link_inertia_kg_m2",
              "link inertia at the joint, kg·m² (the rotor's is left alone)", lower_open=True),
    Parameter("gear_ratio", "gear", "ratio", "plant_gear_ratio", "Harmonic Drive ratio N", lower_open=True),
    Parameter("adc_noise", "crate.adc", "noise_rms_v", "plant_adc_noise_rms_v",
              "ADC input noise, V rms (every ADC board of the crate)"),
)}
ALIASES = {"coulomb_friction": "coulomb", "viscous_friction": "viscous", "ripple_fraction": "ripple",
           "brush_drop": "tach_brush_drop", "ratio": "gear_ratio"}

_SPREAD = re.compile(r"^(?:(?P<dist>[a-z]+)\s*:\s*)?(?:±|\+-|\+/-)?\s*(?P<num>[^%\s]+)\s*(?P<pct>%)?$")


@dataclass(frozen=True)
class Spread:
    """One ``--vary`` term: ``dist`` "uniform" (±magnitude) or "normal" (σ = magnitude), relative
    (``percent``) or absolute (SI units of the parameter)."""

    param: str
    dist: str
    magnitude: float
    percent: bool

    def text(self) -> str:
        """The canonical spelling (parses back to the same spread)."""
        return f"{self.param}={self.dist}:{self.magnitude!r}{'%' if self.percent else ''}"

    def half_width(self, nominal: float) -> float:
        """The largest departure from ``nominal`` a draw can make (SI)."""
        k = 1.0 if self.dist == "uniform" else TRUNCATE_SIGMA
        return k * self.magnitude * (abs(nominal) / 100.0 if self.percent else 1.0)


def parse_vary(text: str) -> Spread:
    """``PARAM=SPREAD`` (module docstring); :class:`VaryError` says what was wrong and what to write."""
    names = ", ".join(PARAMETERS)
    name, sep, spread = text.partition("=")
    name = name.strip().lower()
    if not sep or not name:
        raise VaryError(f"--vary {text!r}: write PARAM=SPREAD, e.g. coulomb=±20% or tach_brush_drop=normal:30% "
                        f"(parameters: {names})")
    name = ALIASES.get(name, name)
    if name not in PARAMETERS:
        raise VaryError(f"--vary {text!r}: unknown parameter {name!r}; one of {names}")
    m = _SPREAD.match(spread.strip().lower())
    if m is None:
        raise VaryError(f"--vary {text!r}: the spread is [uniform:|normal:][±]NUMBER[%], e.g. ±20%, normal:30%, "
                        "uniform:0.001")
    dist = m["dist"] or "uniform"
    if dist not in ("uniform", "normal"):
        raise VaryError(f"--vary {text!r}: distribution {dist!r} is not uniform or normal")
    try:
        value = float(m["num"])
    except ValueError:
        raise VaryError(f"--vary {text!r}: {m['num']!r} is not a number") from None
    if not (math.isfinite(value) and value >= 0):
        raise VaryError(f"--vary {text!r}: the spread must be a finite number ≥ 0, got {m['num']}")
    return Spread(name, dist, value, m["pct"] is not None)


def parse_varies(texts: Iterable[str]) -> list[Spread]:
    """Several ``--vary`` terms; a parameter given twice is an error."""
    out: list[Spread] = []
    for t in texts:
        s = parse_vary(t)
        if any(o.param == s.param for o in out):
            raise VaryError(f"--vary: parameter {s.param} is given twice")
        out.append(s)
    return out


# ----------------------------------------------------------------------- nominal values


def nominal_values(rig_data: dict[str, Any], joint: int, source: str = "<rig>") -> dict[str, float]:
    """The plant's value of every :data:`PARAMETERS` entry for ``joint`` (1-based) as the emulated
    rig builds it from ``rig_data`` (a parsed rig file), defaults included."""
    from emulators.plant import plant_params_from_config
    from hal.config import ConfigTable
    from vmehil.rig_setup.system import NON_PLANT_JOINT_KEYS

    p = plant_params_from_config(ConfigTable(rig_data, source), foreign_keys=NON_PLANT_JOINT_KEYS).joints[joint - 1]
    adcs = _adc_boards(rig_data)
    return {"coulomb": p.friction.coulomb_nm, "viscous": p.friction.viscous_nm_s_per_rad,
            "ripple": p.friction.ripple_fraction, "tach_brush_drop": p.tach.brush_drop_v,
            "inertia": p.link.inertia_kg_m2, "gear_ratio": p.gear.ratio,
            "adc_noise": float(adcs[0].get("noise_rms_v", 0.0)) if adcs else 0.0}


def check_spreads(spreads: list[Spread], nominal: dict[str, float]) -> None:
    """Refuse a spread that can draw a value outside its parameter's range, or a percent of zero."""
    for s in spreads:
        p = PARAMETERS[s.param]
        nom = nominal[s.param]
        if s.percent and nom == 0 and s.magnitude > 0:
            raise VaryError(f"--vary {s.text()}: the nominal {p.key} is 0, so a percent spread varies nothing; "
                            f"give an absolute spread (e.g. {s.param}={s.dist}:0.001)")
        w = s.half_width(nom)
        lo, hi = nom - w, nom + w
        low_bad = lo <= p.lower if p.lower_open else lo < p.lower
        if low_bad or hi >= p.upper:
            rng = f"{'(' if p.lower_open else '['}{p.lower:g}, {p.upper:g})"
            extent = "±" + ("3σ" if s.dist == "normal" else "half-width")
            raise VaryError(f"--vary {s.text()}: draws from {lo:.6g} to {hi:.6g} ({extent} around the nominal "
                            f"{nom:.6g}) leave the range {rng} of {p.what}; use a smaller spread")


def draw_samples(spreads: list[Spread], nominal: dict[str, float], n: int, seed: int) -> list[dict[str, float]]:
    """``n`` samples: for each, the drawn value (SI) of every varied parameter, in ``spreads`` order.
    Sample k uses ``numpy.random.default_rng([seed, k])`` alone."""
    check_spreads(spreads, nominal)
    out = []
    for k in range(n):
        rng = np.random.default_rng([seed, k])
        values = {}
        for s in spreads:
            nom = nominal[s.param]
            scale = s.magnitude * (abs(nom) / 100.0 if s.percent else 1.0)
            if s.dist == "uniform":
                z = float(rng.uniform(-1.0, 1.0))
            else:
                z = float(rng.standard_normal())
                while abs(z) > TRUNCATE_SIGMA:
                    z = float(rng.standard_normal())
            values[s.param] = nom + z * scale if scale else nom
        out.append(values)
    return out


# ------------------------------------------------------------------------ the plant side


def _adc_boards(rig_data: dict[str, Any]) -> list[dict[str, Any]]:
    return [b for b in rig_data.get("crate", {}).get("board", []) if b.get("type") == "adc"]


def apply_plant_values(rig_data: dict[str, Any], joint: int, values: dict[str, float],
                       nominal: dict[str, float] | None = None) -> dict[str, Any]:
    """A copy of ``rig_data`` whose plant tables of ``joint`` (1-based) carry ``values`` (SI, by
    parameter name). Only plant/electronics tables change; ``[joint.servo]`` (the controller's
    nominal values) is never touched. ``coulomb`` scales ``breakout_nm`` by the same ratio (so the
    breakout stays above the kinetic level); ``nominal`` (default: :func:`nominal_values`) gives it."""
    if not values:
        return rig_data
    out = copy.deepcopy(rig_data)
    nominal = nominal if nominal is not None else nominal_values(rig_data, joint)
    jt = out["joint"][joint - 1]
    for name, v in values.items():
        p = PARAMETERS[name]
        if p.section == "crate.adc":
            for b in _adc_boards(out):
                b[p.key] = float(v)
            continue
        table = jt.setdefault(p.section, {})
        table[p.key] = float(v)
        if name == "coulomb" and nominal["coulomb"] > 0:
            from emulators.plant import plant_params_from_config
            from hal.config import ConfigTable
            from vmehil.rig_setup.system import NON_PLANT_JOINT_KEYS

            base = plant_params_from_config(ConfigTable(rig_data, "<rig>"),
                                            foreign_keys=NON_PLANT_JOINT_KEYS).joints[joint - 1]
            table["breakout_nm"] = base.friction.breakout_nm * (float(v) / nominal["coulomb"])
    return out
