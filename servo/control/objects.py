"""Control objects ((DM)² style): controllers composed at run time from named objects.

A controller is an ordered list of objects. Each tick the controller builds a
:class:`ControlContext` (measurements, trajectory sample, period, normalizing chain) and folds
the torque through the objects::

    tau = 0
    for obj in objects:
        tau = obj.update(ctx, tau)      # a source adds its contribution, a transform (limiter) maps tau

Sources: ``pid`` (the JPL law, :mod:`servo.control.law`), ``friction_comp``, ``gravity_comp``.
Transform: ``torque_limit`` (records per-joint saturation in ``ctx.saturation``).

Anti-windup (conditional integration): after the first pass, for every joint whose output
saturated, each object's :meth:`BaseControlObject.windup_push` (the direction this tick's
integration drives the torque) is compared with the saturation side; where they agree
(integration would deepen the saturation) the tick is re-evaluated with that joint's integration
withheld (``ctx.windup_block``). Then :meth:`BaseControlObject.commit` stores the state. So an
integrator never grows while the output is pinned at the limit in its direction, and it still
unwinds (integration towards the inside is allowed).

Objects are named in :data:`CONTROL_OBJECTS` (the built-ins, plus the entry points of group
``vmehil.control_objects`` that installed packages declare) and built from a TOML table by
:func:`build_controller`::

    [joint.servo.controller]
    objects = ["pid", "friction_comp", "torque_limit"]
    [joint.servo.controller.pid]
    kp = 100.0                    # scalars apply to every joint, lists give one value per joint
    switch_off = { enabled = true, inner_band_deg = 0.1, outer_band_deg = 1.0, kp_boost = "auto" }
    [joint.servo.controller.friction_comp]
    coulomb_motor_nm = 0.042
    [joint.servo.controller.torque_limit]
    current_max_a = 6.0
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar, Protocol, cast, runtime_checkable

import numpy as np

from hal.config import ConfigError, ConfigTable
from hal.plugins import PluginTable
from hal.si import deg_to_rad
from servo.control.errors import ControlError, GainError
from servo.control.gains import DEFAULT_GAINS, GAIN_NAMES, Gains
from servo.control.law import (
    DEFAULT_INNER_BAND_RAD,
    DEFAULT_OUTER_BAND_RAD,
    DEFAULT_PERIOD_S,
    PidLaw,
    SwitchEvent,
    SwitchOffConfig,
)
from servo.control.normalize import NormalizingChain, per_joint

STANDARD_GRAVITY = 9.80665  # m/s²


@dataclass
class ControlContext:
    """Everything an object may look at in one tick (arrays of length n, SI units).

    Inputs: ``tick``, ``t`` s, ``dt`` s, ``theta`` rad and ``omega`` rad/s measured at the joint,
    ``theta_d``/``omega_d``/``alpha_d`` from the trajectory, ``motion_done`` (trajectory says done),
    ``chain`` the normalizing chain. Written by objects: ``saturation`` (−1/0/+1 per joint, set by
    limiters), ``torque_unlimited`` N·m (before the first limiter), ``accel`` rad/s² (the law's
    normalized output), ``windup_block`` (set by the controller on its second pass).
    """

    tick: int
    t: float
    dt: float
    theta: np.ndarray
    omega: np.ndarray
    theta_d: np.ndarray
    omega_d: np.ndarray
    alpha_d: np.ndarray
    motion_done: bool | np.ndarray
    chain: NormalizingChain
    saturation: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int8))
    torque_unlimited: np.ndarray | None = None
    accel: np.ndarray | None = None
    windup_block: np.ndarray | None = None


@runtime_checkable
class ControlObject(Protocol):
    """The protocol: ``update(ctx, tau) -> tau``. Sources return ``tau + contribution``, transforms
    return a function of ``tau``. Optional hooks are in :class:`BaseControlObject`."""

    name: str

    def update(self, ctx: ControlContext, tau: np.ndarray) -> np.ndarray: ...


class BaseControlObject:
    """Base class with no-op hooks. Subclasses set ``kind`` ("source" or "transform")."""

    kind: ClassVar[str] = "source"
    name: str = ""

    def update(self, ctx: ControlContext, tau: np.ndarray) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def windup_push(self, ctx: ControlContext) -> np.ndarray | None:
        """Direction (sign, in torque) this tick's integration drives the output, or None if stateless."""
        return None

    def commit(self, ctx: ControlContext) -> None:
        """End of tick: store state computed in :meth:`update`."""

    def export_state(self) -> Any:
        """State to hand to a same-named object of the next controller on a swap (None: stateless)."""
        return None

    def import_state(self, state: Any) -> None:
        """Take over state exported by the previous controller's same-named object."""

    def reset(self) -> None:
        """Clear internal state."""

    def preload_torque(self, torque: np.ndarray, chain: NormalizingChain) -> None:
        """After :meth:`reset`: start so that with zero error the output is ``torque`` (N·m per
        joint; 0: as reset) — a resume whose holding brakes kept the joints where they stopped."""

    def describe(self) -> dict[str, Any]:
        """Parameters for reports (SI, keys carry units)."""
        return {}

    @classmethod
    def from_lanes(cls, objects: Sequence[BaseControlObject]) -> BaseControlObject:
        """One object for B lanes of ``objects`` (batched lockstep, :mod:`hal.lanes`): per-joint
        parameters and state concatenated lane-major. An object type that does not say how cannot
        run in lanes."""
        raise NotImplementedError(f"control object {objects[0].name!r} ({cls.__name__}) cannot run in lanes")

    def write_lane(self, lane: int, obj: BaseControlObject) -> None:
        """Put lane ``lane``'s state of this lane object into ``obj`` (its scalar object); stateless: nothing."""


ObjectFactory = Callable[[ConfigTable, int, NormalizingChain, float], BaseControlObject]
"""``factory(cfg, n, chain, period) -> object``: ``cfg`` is the object's sub-table of the controller
table (e.g. ``[...controller.pid]``), ``n`` the number of joints, ``period`` the servo period in s."""


# ---- config helpers ---------------------------------------------------------------------------------
def cfg_per_joint(cfg: ConfigTable, key: str, n: int, default: Any, *, positive: bool = False,
                  deg_key: str | None = None) -> np.ndarray:
    """A per-joint value from ``cfg[key]`` (scalar or list of n); with ``deg_key`` the value may be
    given in degrees instead (converted with hal.si). Errors name the file and key."""
    if deg_key is not None and deg_key in cfg:
        if key in cfg:
            raise cfg.error(deg_key, f"either {key} or {deg_key}, not both")
        key, conv = deg_key, deg_to_rad
    else:
        conv = None
    value = cfg.raw(key, default)
    try:
        arr = per_joint(key, value, n, positive=positive)
    except GainError as e:
        where = f" (joint {e.joint})" if e.joint is not None else ""
        raise cfg.error(key, e.expected + where, value) from None
    return conv(arr) if conv is not None else arr


# ---- the objects ----------------------------------------------------------------------------------------
class PidObject(BaseControlObject):
    """The JPL law as a source: τ += J_eff·a (see :class:`servo.control.law.PidLaw`)."""

    def __init__(self, law: PidLaw, name: str = "pid") -> None:
        self.law = law
        self.name = name

    @classmethod
    def from_config(cls, cfg: ConfigTable, n: int, chain: NormalizingChain, period: float) -> PidObject:
        """Keys: kp, kpi, kv, kvi (scalar or per joint; defaults 100, 5000, 50, 1000) and an optional
        ``switch_off`` table: enabled, inner_band_rad|_deg, outer_band_rad|_deg, kp_boost (number or
        "auto"), settle_time_s, zero_crossing."""
        gains = Gains(*(cfg_per_joint(cfg, k, n, DEFAULT_GAINS[k]) for k in GAIN_NAMES))
        so = parse_switch_off(cfg.table("switch_off", {}), n)
        cfg.check_unknown({*GAIN_NAMES, "switch_off"})
        return cls(PidLaw(n, period, gains, so))

    def update(self, ctx: ControlContext, tau: np.ndarray) -> np.ndarray:
        if ctx.windup_block is None:
            self.law.begin(ctx.tick, ctx.theta, ctx.omega, ctx.theta_d, ctx.omega_d, ctx.motion_done)
        a = self.law.evaluate(ctx.alpha_d, ctx.windup_block)
        ctx.accel = a if ctx.accel is None else ctx.accel + a
        return tau + ctx.chain.torque_from_accel(a)

    def windup_push(self, ctx: ControlContext) -> np.ndarray:
        return ctx.chain.torque_from_accel(self.law.integration_push())

    def commit(self, ctx: ControlContext) -> None:
        self.law.commit()

    def export_state(self) -> Any:
        return self.law.export_state()

    def import_state(self, state: Any) -> None:
        self.law.import_state(state)

    def reset(self) -> None:
        self.law.reset()

    def preload_torque(self, torque: np.ndarray, chain: NormalizingChain) -> None:
        self.law.preload(np.asarray(torque, float) / chain.j_eff)

    @classmethod
    def from_lanes(cls, objects: Sequence[BaseControlObject]) -> PidObject:
        return cls(PidLaw.from_lanes([cast(PidObject, o).law for o in objects]), objects[0].name)

    def write_lane(self, lane: int, obj: BaseControlObject) -> None:
        self.law.write_lane(lane, cast(PidObject, obj).law)

    def describe(self) -> dict[str, Any]:
        so = self.law.switch_off
        return {
            "gains": self.law.gains.as_dict(),
            "switch_off": {
                "enabled": [bool(x) for x in so.enabled],
                "inner_band_rad": [float(x) for x in so.inner_band],
                "outer_band_rad": [float(x) for x in so.outer_band],
                "kp_boost": [None if math.isnan(x) else float(x) for x in so.kp_boost],
                "kp_off": [float(x) for x in self.law.kp_off()],
                "settle_time_s": [float(x) for x in so.settle_time],
            },
        }


def parse_switch_off(cfg: ConfigTable, n: int) -> SwitchOffConfig:
    """Parse a ``switch_off`` table (see :meth:`PidObject.from_config`); errors name file and key."""
    enabled = cfg.raw("enabled", True)
    zero_crossing = cfg.raw("zero_crossing", True)
    for key, val in (("enabled", enabled), ("zero_crossing", zero_crossing)):
        if not (isinstance(val, bool) or (isinstance(val, list) and all(isinstance(x, bool) for x in val))):
            raise cfg.error(key, "true/false or a list of them", val)
    inner = cfg_per_joint(cfg, "inner_band_rad", n, DEFAULT_INNER_BAND_RAD, deg_key="inner_band_deg")
    outer = cfg_per_joint(cfg, "outer_band_rad", n, DEFAULT_OUTER_BAND_RAD, deg_key="outer_band_deg")
    boost_raw = cfg.raw("kp_boost", "auto")
    if boost_raw == "auto":
        boost: Any = None
    elif isinstance(boost_raw, list):
        boost = [None if b == "auto" else b for b in boost_raw]
    else:
        boost = boost_raw
    settle = cfg_per_joint(cfg, "settle_time_s", n, 0.0)
    cfg.check_unknown({"enabled", "zero_crossing", "inner_band_rad", "inner_band_deg", "outer_band_rad",
                       "outer_band_deg", "kp_boost", "settle_time_s"})
    try:
        return SwitchOffConfig.make(n, enabled=enabled, inner_band=inner, outer_band=outer, kp_boost=boost,
                                    settle_time=settle, zero_crossing=zero_crossing)
    except GainError as e:
        key = e.name.split(".", 1)[-1]
        if key in ("inner_band", "outer_band"):
            key += "_deg" if f"{key}_deg" in cfg else "_rad"
        elif key == "settle_time":
            key = "settle_time_s"
        where = f" (joint {e.joint})" if e.joint is not None else ""
        raise ConfigError(cfg.source, cfg.key(key), e.expected + where, e.value) from None


class TorqueLimit(BaseControlObject):
    """Transform: clip τ to ±tau_max per joint (N·m at the joint); sets ``ctx.saturation``."""

    kind: ClassVar[str] = "transform"

    def __init__(self, tau_max: np.ndarray, name: str = "torque_limit") -> None:
        self.tau_max = np.asarray(tau_max, float)
        self.name = name

    @classmethod
    def from_config(cls, cfg: ConfigTable, n: int, chain: NormalizingChain, period: float) -> TorqueLimit:
        """Keys (at least one; the tightest wins): ``tau_max_nm`` at the joint, ``current_max_a`` motor
        current, ``volts_max_v`` amplifier command — converted to torque through the chain."""
        limits = []
        if "tau_max_nm" in cfg:
            limits.append(cfg_per_joint(cfg, "tau_max_nm", n, None, positive=True))
        if "current_max_a" in cfg:
            limits.append(chain.torque_from_current(cfg_per_joint(cfg, "current_max_a", n, None, positive=True)))
        if "volts_max_v" in cfg:
            limits.append(chain.torque_from_volts(cfg_per_joint(cfg, "volts_max_v", n, None, positive=True)))
        cfg.check_unknown({"tau_max_nm", "current_max_a", "volts_max_v"})
        if not limits:
            raise cfg.error("tau_max_nm", "a limit: tau_max_nm, current_max_a or volts_max_v")
        return cls(np.minimum.reduce(limits))

    def update(self, ctx: ControlContext, tau: np.ndarray) -> np.ndarray:
        if ctx.torque_unlimited is None:
            ctx.torque_unlimited = tau.copy()
        sat = np.where(tau > self.tau_max, 1, np.where(tau < -self.tau_max, -1, 0)).astype(np.int8)
        ctx.saturation = np.where(ctx.saturation != 0, ctx.saturation, sat).astype(np.int8)
        return np.clip(tau, -self.tau_max, self.tau_max)

    @classmethod
    def from_lanes(cls, objects: Sequence[BaseControlObject]) -> TorqueLimit:
        return cls(np.concatenate([cast(TorqueLimit, o).tau_max for o in objects]), objects[0].name)

    def describe(self) -> dict[str, Any]:
        return {"tau_max_nm": [float(x) for x in self.tau_max]}


class FrictionComp(BaseControlObject):
    """Source: Coulomb + viscous friction feedforward, identified at the motor, referred to the joint.

    τ = N·Tc·sgn(ω) (zero when |ω| < dead_zone) + N²·b·ω, with ω the joint velocity (desired by
    default, or measured), Tc N·m and b N·m·s/rad at the motor shaft, N the ratio from the chain.
    """

    def __init__(self, coulomb_motor: np.ndarray, viscous_motor: np.ndarray, dead_zone: np.ndarray,
                 use_measured: bool = False, name: str = "friction_comp") -> None:
        self.coulomb_motor = np.asarray(coulomb_motor, float)
        self.viscous_motor = np.asarray(viscous_motor, float)
        self.dead_zone = np.asarray(dead_zone, float)
        self.use_measured = use_measured
        self.name = name

    @classmethod
    def from_config(cls, cfg: ConfigTable, n: int, chain: NormalizingChain, period: float) -> FrictionComp:
        """Keys: coulomb_motor_nm (default 0), viscous_motor_nm_s_per_rad (default 0), dead_zone_rad_s
        (joint velocity, default 0.005), velocity = "desired" | "measured" (default desired)."""
        obj = cls(cfg_per_joint(cfg, "coulomb_motor_nm", n, 0.0),
                  cfg_per_joint(cfg, "viscous_motor_nm_s_per_rad", n, 0.0),
                  cfg_per_joint(cfg, "dead_zone_rad_s", n, 0.005),
                  cfg.get_str("velocity", "desired", choices=("desired", "measured")) == "measured")
        cfg.check_unknown()
        return obj

    def update(self, ctx: ControlContext, tau: np.ndarray) -> np.ndarray:
        w = ctx.omega if self.use_measured else ctx.omega_d
        n = ctx.chain.ratio
        coulomb = np.where(np.abs(w) < self.dead_zone, 0.0, np.sign(w) * n * self.coulomb_motor)
        return tau + coulomb + n * n * self.viscous_motor * w

    @classmethod
    def from_lanes(cls, objects: Sequence[BaseControlObject]) -> FrictionComp:
        objs = [cast(FrictionComp, o) for o in objects]
        if len({o.use_measured for o in objs}) != 1:
            raise NotImplementedError("friction_comp: lanes differ in the velocity they use")
        return cls(np.concatenate([o.coulomb_motor for o in objs]), np.concatenate([o.viscous_motor for o in objs]),
                   np.concatenate([o.dead_zone for o in objs]), objs[0].use_measured, objs[0].name)

    def describe(self) -> dict[str, Any]:
        return {"coulomb_motor_nm": self.coulomb_motor.tolist(),
                "viscous_motor_nm_s_per_rad": self.viscous_motor.tolist(),
                "dead_zone_rad_s": self.dead_zone.tolist(),
                "velocity": "measured" if self.use_measured else "desired"}


class GravityComp(BaseControlObject):
    """Source: τ = m·g·l·cos(θ + offset) per joint (θ desired by default, or measured)."""

    def __init__(self, mgl: np.ndarray, offset: np.ndarray, use_measured: bool = False,
                 name: str = "gravity_comp") -> None:
        self.mgl = np.asarray(mgl, float)
        self.offset = np.asarray(offset, float)
        self.use_measured = use_measured
        self.name = name

    @classmethod
    def from_config(cls, cfg: ConfigTable, n: int, chain: NormalizingChain, period: float) -> GravityComp:
        """Keys: mass_kg and com_m (distance joint axis → centre of mass), or mgl_nm directly;
        offset_rad|offset_deg (default 0); g_m_s2 (default 9.80665); angle = "desired" | "measured"."""
        if "mgl_nm" in cfg:
            if "mass_kg" in cfg or "com_m" in cfg:
                raise cfg.error("mgl_nm", "either mgl_nm or mass_kg and com_m, not both")
            mgl = cfg_per_joint(cfg, "mgl_nm", n, None)
        else:
            g = cfg.get_float("g_m_s2", STANDARD_GRAVITY, min=0.0)
            mgl = cfg_per_joint(cfg, "mass_kg", n, None) * g * cfg_per_joint(cfg, "com_m", n, None)
        offset = cfg_per_joint(cfg, "offset_rad", n, 0.0, deg_key="offset_deg")
        use_measured = cfg.get_str("angle", "desired", choices=("desired", "measured")) == "measured"
        cfg.check_unknown({"mgl_nm", "mass_kg", "com_m", "g_m_s2", "offset_rad", "offset_deg", "angle"})
        return cls(mgl, offset, use_measured)

    def update(self, ctx: ControlContext, tau: np.ndarray) -> np.ndarray:
        th = ctx.theta if self.use_measured else ctx.theta_d
        return tau + self.mgl * np.cos(th + self.offset)

    def describe(self) -> dict[str, Any]:
        return {"mgl_nm": self.mgl.tolist(), "offset_rad": self.offset.tolist(),
                "angle": "measured" if self.use_measured else "desired"}


# ---- the controller ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class ControlOutput:
    """One tick's output (arrays of length n): ``accel`` rad/s² (the law's normalized output, 0 if
    no pid), ``torque`` N·m after limits, ``torque_unlimited`` N·m, ``saturation`` −1/0/+1,
    ``integrating`` (switch-off state: True = integrators fed).

    The torque is the command: the drivers turn it into amperes, volts and DAC codes with the
    calibrated scaling (:meth:`servo.io.JointIO.write_torque`, the one conversion), not here."""

    accel: np.ndarray
    torque: np.ndarray
    torque_unlimited: np.ndarray
    saturation: np.ndarray
    integrating: np.ndarray


class Controller:
    """An ordered composition of control objects for ``n`` joints."""

    def __init__(self, objects: list[BaseControlObject], chain: NormalizingChain,
                 period: float = DEFAULT_PERIOD_S) -> None:
        names = [o.name for o in objects]
        if len(set(names)) != len(names):
            raise ControlError(f"control object names must be unique, got {names}")
        self.objects = list(objects)
        self.chain = chain
        self.period = float(period)
        self.n = chain.n

    @classmethod
    def from_lanes(cls, controllers: Sequence[Controller]) -> Controller:
        """One controller for B lanes (batched lockstep, :mod:`hal.lanes`): the same objects in the
        same order in every lane, each stacked by its type's ``from_lanes``; the chain's per-joint
        gains concatenated lane-major. :meth:`update` then runs unchanged: every operation is
        elementwise, and the anti-windup second pass, run for every lane when any lane saturates,
        gives the lanes that did not the numbers of their first pass again."""
        first = controllers[0]
        kinds = [(type(o), o.name) for o in first.objects]
        for c in controllers:
            if [(type(o), o.name) for o in c.objects] != kinds or c.period != first.period:
                raise NotImplementedError("lanes' controllers differ in their objects or period")
        objects = [kind.from_lanes([c.objects[i] for c in controllers]) for i, (kind, _) in enumerate(kinds)]
        chains = [c.chain for c in controllers]
        chain = NormalizingChain(*(np.concatenate([getattr(ch, f) for ch in chains]) for f in (
            "j_eff", "ratio", "kt", "amp_gain", "dac_volts_per_count")))
        return cls(objects, chain, first.period)

    def write_lane(self, lane: int, controller: Controller) -> None:
        """Put lane ``lane``'s state (integrators, switch-off) into ``controller``, its scalar one."""
        for mine, theirs in zip(self.objects, controller.objects, strict=True):
            mine.write_lane(lane, theirs)

    def find(self, name: str) -> BaseControlObject | None:
        for o in self.objects:
            if o.name == name:
                return o
        return None

    @property
    def law(self) -> PidLaw | None:
        """The first pid object's law (for gains, switch-off state and events), if any."""
        for o in self.objects:
            if isinstance(o, PidObject):
                return o.law
        return None

    @property
    def events(self) -> list[SwitchEvent]:
        law = self.law
        return law.events if law is not None else []

    def _pass(self, ctx: ControlContext) -> np.ndarray:
        ctx.saturation = np.zeros(self.n, np.int8)
        ctx.torque_unlimited = None
        ctx.accel = None
        tau = np.zeros(self.n)
        for o in self.objects:
            tau = o.update(ctx, tau)
        return tau

    def update(self, ctx: ControlContext) -> ControlOutput:
        """Run one tick (see the module docstring for the anti-windup second pass)."""
        ctx.windup_block = None
        tau = self._pass(ctx)
        if np.any(ctx.saturation != 0):
            block = np.zeros(self.n, bool)
            for o in self.objects:
                push = o.windup_push(ctx)
                if push is not None:
                    block |= (ctx.saturation != 0) & (np.sign(push) == ctx.saturation)
            if block.any():
                ctx.windup_block = block
                tau = self._pass(ctx)
        for o in self.objects:
            o.commit(ctx)
        law = self.law
        return ControlOutput(
            accel=ctx.accel if ctx.accel is not None else np.zeros(self.n),
            torque=tau,
            torque_unlimited=ctx.torque_unlimited if ctx.torque_unlimited is not None else tau.copy(),
            saturation=ctx.saturation.copy(),
            integrating=law.integrating if law is not None else np.zeros(self.n, bool),
        )

    def step(self, tick: int, theta: np.ndarray, omega: np.ndarray, theta_d: np.ndarray, omega_d: np.ndarray,
             alpha_d: np.ndarray | float = 0.0, motion_done: bool | np.ndarray = False) -> ControlOutput:
        """Convenience: build the context for tick ``tick`` (t = tick·period) and :meth:`update`."""
        ctx = ControlContext(
            tick=tick, t=tick * self.period, dt=self.period, theta=np.asarray(theta, float),
            omega=np.asarray(omega, float), theta_d=np.asarray(theta_d, float),
            omega_d=np.asarray(omega_d, float), alpha_d=np.broadcast_to(np.asarray(alpha_d, float), (self.n,)),
            motion_done=motion_done, chain=self.chain)
        return self.update(ctx)

    def take_state_from(self, other: Controller) -> list[str]:
        """Import the state of same-named objects of ``other`` (e.g. integrators); returns their names."""
        moved = []
        for o in self.objects:
            prev = other.find(o.name)
            if prev is None or type(prev) is not type(o):
                continue
            state = prev.export_state()
            if state is not None:
                o.import_state(state)
                moved.append(o.name)
        return moved

    def describe(self) -> dict[str, Any]:
        return {"objects": [o.name for o in self.objects], "params": {o.name: o.describe() for o in self.objects},
                "chain": self.chain.describe(), "period_s": self.period}


class SwitchableController:
    """Holds the active controller; :meth:`request` swaps it at the next tick boundary, carrying over
    the state of same-named objects (the pid integrators and switch-off state)."""

    def __init__(self, active: Controller) -> None:
        self.active = active
        self._pending: Controller | None = None
        self.swaps: list[tuple[int, list[str]]] = []  # (tick, names of objects whose state was carried over)

    @classmethod
    def from_lanes(cls, switchables: Sequence[SwitchableController]) -> SwitchableController:
        """The lanes' active controllers stacked (:meth:`Controller.from_lanes`); a swap pending
        cannot run in lanes."""
        if any(s._pending is not None for s in switchables):
            raise NotImplementedError("a controller swap is pending: it cannot run in lanes")
        return cls(Controller.from_lanes([s.active for s in switchables]))

    def request(self, new: Controller) -> None:
        if new.n != self.active.n:
            raise ControlError(f"new controller has {new.n} joints, the active one {self.active.n}")
        self._pending = new

    def update(self, ctx: ControlContext) -> ControlOutput:
        if self._pending is not None:
            moved = self._pending.take_state_from(self.active)
            self.active, self._pending = self._pending, None
            self.swaps.append((ctx.tick, moved))
        return self.active.update(ctx)


BUILTIN_CONTROL_OBJECTS: dict[str, ObjectFactory] = {
    "pid": PidObject.from_config,
    "torque_limit": TorqueLimit.from_config,
    "friction_comp": FrictionComp.from_config,
    "gravity_comp": GravityComp.from_config,
}


def _factory(name: str, obj: Any) -> ObjectFactory:
    if not callable(obj):
        raise TypeError(f"a control object is a factory (cfg, n, chain, period) -> object, not {type(obj).__name__}")
    return obj


#: The objects a controller table can name: the built-ins, plus the entry points of group
#: ``vmehil.control_objects`` (e.g. ``damper = "acme.servo:Damper.from_config"``; docs/architecture.md).
CONTROL_OBJECTS: PluginTable[ObjectFactory] = PluginTable("vmehil.control_objects", "control object",
                                                          BUILTIN_CONTROL_OBJECTS, _factory)


def build_controller(table: ConfigTable | dict[str, Any], chain: NormalizingChain,
                     period: float = DEFAULT_PERIOD_S, source: str = "<controller config>") -> Controller:
    """Build a :class:`Controller` from a parsed controller table (``[...servo.controller]``).

    ``objects`` (list of names in :data:`CONTROL_OBJECTS`, default ``["pid"]``) gives the order; each object's
    parameters come from the sub-table of the same name (optional for pid). Errors are
    :class:`hal.config.ConfigError` naming the file and the key.
    """
    cfg = table if isinstance(table, ConfigTable) else ConfigTable(table, source)
    names = cfg.raw("objects", ["pid"])
    if not isinstance(names, list) or not all(isinstance(x, str) for x in names) or not names:
        raise cfg.error("objects", "a non-empty list of control object names", names)
    objects: list[BaseControlObject] = []
    for i, name in enumerate(names):
        factory = CONTROL_OBJECTS.get(name)
        if factory is None:
            raise cfg.error(f"objects[{i}]", "one of " + ", ".join(CONTROL_OBJECTS.names()), name)
        if name in names[:i]:
            raise cfg.error(f"objects[{i}]", "each object at most once", name)
        sub = cfg.table(name, {})
        objects.append(factory(sub, chain.n, chain, period))
    cfg.check_unknown({"objects", *names})
    return Controller(objects, chain, period)
