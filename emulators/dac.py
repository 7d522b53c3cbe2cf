"""Register-level emulator of the 8-channel 12-bit double-buffered DAC, written from ``docs/boards/dac.md``.

A second reading of the board, independent of the driver (:mod:`hal.adc_dac`, which it does not
import): its register map, ID and code → volts conversion are its own literal Python, written
from the doc's register table and coding. Tests check both this map and the driver's against the
doc's table (tests/hal/test_dac.py), never against each other.

Behaviour (see ``docs/boards/dac.md``):

* Power-up and reset: every holding and output register is 0x800, every output 0 V (plus the
  channel's offset error).
* Writing ``DATAn`` loads the holding register only. ``UPDATE`` bit *n* (or ``CSR.UPDATE_ALL``)
  copies holding → output for all selected channels in the same instant.
* Output: ``v = ideal(code)·(1 + gain_error) + offset_v``, clipped at the ±``rail_v`` output
  stage rails. It settles first-order: :meth:`DacBoard.output_volts` gives the exponential
  approach at any instant (τ = settling time / ln 8192, i.e. a full-scale step is within
  ½ LSB at the settling time); the wired analog net is set to the final value one settling
  time after the strobe (a newer strobe supersedes). ``CSR.SETTLING`` reads 1 meanwhile.

Fault: ``dead_channel(channel, volts=0.0)`` — the output pin sits at ``volts`` whatever is
written (the registers still read back what was written, as on a board with a blown output
buffer).

Lanes (batched lockstep, :mod:`hal.lanes`): :meth:`DacBoard.from_lanes` stacks B boards into
one whose registers, offset/gain errors, rails and output volts are lane values; the strobes,
and so the settling events, are the same instants in every lane (one clock). Injected faults
are not carried into lanes (those runs go scalar).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from functools import partial
from typing import Any, ClassVar

import numpy as np

from emulators.adc import per_channel, wiring_from_config
from emulators.board import Backplane, RegisterBoard
from emulators.board_factory import BuildContext
from hal.config import ConfigTable
from hal.lanes import LaneValue, stack
from hal.vme.registers import Access, Field, Register, RegisterMap
from hal.vme.types import AddressSpace, Width

# --- the board, as docs/boards/dac.md states it ------------------------------------------------
DAC_BOARD_ID = 0xDA08  #: the ID register
DAC_CHANNELS = 8
CODE_MAX = 0xFFF
DAC_POWER_UP_CODE = 0x800  #: 0 V in offset binary: every DATAn and OUTn after power-up/reset
DEFAULT_SETTLING_NS = 10_000

_CODE = (Field("CODE", 0, 12),)  # [11:0] CODE; bits 15:12 ignored on write, read 0
REGMAP = RegisterMap(
    "dac8",
    0x30,  # the window: OUT7 at 0x2E is the last register
    AddressSpace.A16,
    (
        Register("ID", 0x00, Width.D16, Access.RO, reset=0xDA08, also=(Width.D8,)),
        Register("CSR", 0x02, Width.D16, Access.RW,
                 (Field("RESET", 15), Field("SETTLING", 1), Field("UPDATE_ALL", 0)), also=(Width.D8,)),
        Register("UPDATE", 0x04, Width.D16, Access.WO, tuple(Field(f"CH{n}", n) for n in range(8)),
                 also=(Width.D8,)),
        *(Register(f"DATA{n}", 0x10 + 2 * n, Width.D16, Access.RW, _CODE, reset=0x800) for n in range(8)),
        *(Register(f"OUT{n}", 0x20 + 2 * n, Width.D16, Access.RO, _CODE, reset=0x800) for n in range(8)),
    ),
    doc="emulated 8-channel 12-bit ±10 V double-buffered DAC (docs/boards/dac.md)",
)

#: volts per code: the ±10 V span over 4096 codes (4.8828125 mV, exact in binary)
_LSB_V = 20.0 / 4096
_CSR = REGMAP["CSR"]
_UPDATE_ALL = _CSR.field("UPDATE_ALL").mask
_SETTLING = _CSR.field("SETTLING").mask
_RESET = _CSR.field("RESET").mask
_DATA = tuple(f"DATA{ch}" for ch in range(DAC_CHANNELS))
_OUT = tuple(f"OUT{ch}" for ch in range(DAC_CHANNELS))


class DacBoard(RegisterBoard):
    """Emulated DAC board.

    Args:
        name: board name in the crate.
        wiring: channel → analog net the output drives.
        offset_v: per-channel offset error (V), 8 values.
        gain_error: per-channel gain error (fraction), 8 values.
        settling_time_ns: time from the update strobe to the final value on the net.
        rail_v: output stage saturation (± volts).
    """

    TYPE = "dac"
    REGMAP = REGMAP
    FAULTS: ClassVar[dict[str, str]] = {
        "dead_channel": "channel=N[, volts=V]: output N stuck at V (default 0 V) whatever is written",
    }

    def __init__(
        self,
        name: str,
        *,
        wiring: Mapping[int, str] | None = None,
        offset_v: Sequence[float] | None = None,
        gain_error: Sequence[float] | None = None,
        settling_time_ns: int = DEFAULT_SETTLING_NS,
        rail_v: float = 10.5,
    ) -> None:
        self.wiring: dict[int, str] = {}
        for ch, net in (wiring or {}).items():
            if not 0 <= int(ch) < DAC_CHANNELS:
                raise ValueError(f"{name}: wiring channel {ch} is not 0..{DAC_CHANNELS - 1}")
            self.wiring[int(ch)] = str(net)
        self.offset_v = per_channel(name, "offset_v", offset_v, DAC_CHANNELS)
        self.gain_error = per_channel(name, "gain_error", gain_error, DAC_CHANNELS)
        if settling_time_ns < 0:
            raise ValueError(f"{name}: settling_time_ns must be >= 0")
        self.settling_time_ns = int(settling_time_ns)
        self.tau_ns = self.settling_time_ns / math.log(8192)  # a 20 V step is ½ LSB (1/8192 of it) at settling
        self.rail_v = float(rail_v)
        # per channel: (strobe time ns, converter volts at the strobe, final volts)
        self._step: list[tuple[int, float, float]] = []
        self._gen = [0] * DAC_CHANNELS
        self.updates = 0  #: number of update strobes (diagnostic)
        super().__init__(name)

    # --- power-up / reset ---------------------------------------------------------------
    def reset(self) -> None:
        super().reset()
        v0 = [self._analog(ch, DAC_POWER_UP_CODE) for ch in range(DAC_CHANNELS)]
        self._step = [(self.now_ns, v, v) for v in v0]
        self._gen = [g + 1 for g in self._gen]
        for ch in range(DAC_CHANNELS):
            self._drive(ch)

    def attach(self, crate) -> None:
        super().attach(crate)
        self._step = [(self.now_ns, v, v) for _, _, v in self._step]
        for ch in range(DAC_CHANNELS):
            self._drive(ch)

    # --- analog output ------------------------------------------------------------------
    def _analog(self, ch: int, code: int) -> float:
        v = ideal_volts(code) * (1.0 + self.gain_error[ch]) + self.offset_v[ch]
        return min(max(v, -self.rail_v), self.rail_v)

    def _dead_volts(self, ch: int) -> float | None:
        if not self.faulted:
            return None
        f = self.fault("dead_channel")
        if f is not None and int(f.get("channel", -1)) == ch:
            return float(f.get("volts", 0.0))
        return None

    def output_volts(self, channel: int, t_ns: int | None = None) -> float:
        """The voltage at output pin ``channel`` at ``t_ns`` (default now), settling included."""
        dead = self._dead_volts(channel)
        if dead is not None:
            return dead
        return self._converter_volts(channel, self.now_ns if t_ns is None else t_ns)

    def _converter_volts(self, channel: int, t_ns: int) -> float:
        """The converter's own (settling) output, before any pin fault."""
        t0, v_start, v_final = self._step[channel]
        if self.tau_ns <= 0 or t_ns - t0 >= self.settling_time_ns:
            return v_final
        return v_final + (v_start - v_final) * math.exp(-(t_ns - t0) / self.tau_ns)

    def _drive(self, ch: int) -> None:
        """Put the settled (or dead) output of ``ch`` on its net."""
        net = self.wiring.get(ch)
        if net is None or self.crate is None:
            return
        dead = self._dead_volts(ch)
        self.crate.signals.set_analog(net, dead if dead is not None else self._step[ch][2])

    def _fault_changed(self, name: str) -> None:
        for ch in range(DAC_CHANNELS):
            self._drive(ch)

    def _update(self, mask: int) -> None:
        now = self.now_ns
        for ch in range(DAC_CHANNELS):
            if not mask & (1 << ch):
                continue
            v_now = self._converter_volts(ch, now)
            code = self.regs[_DATA[ch]]
            self.regs[_OUT[ch]] = code
            self._step[ch] = (now, v_now, self._analog(ch, code))
            self._gen[ch] += 1
            gen = self._gen[ch]
            if self.settling_time_ns == 0 or self.crate is None:
                self._drive(ch)
            else:
                self.crate.clock.schedule_in(self.settling_time_ns, partial(self._settled, ch, gen))
        self.updates += 1

    def _settled(self, ch: int, gen: int) -> None:
        if gen == self._gen[ch]:
            self._drive(ch)

    @property
    def settling(self) -> bool:
        now = self.now_ns
        return any(now - t0 < self.settling_time_ns and vs != vf for t0, vs, vf in self._step)

    # --- registers ----------------------------------------------------------------------
    def read_CSR(self) -> int:
        return _SETTLING if self.settling else 0

    def write_CSR(self, value: int) -> None:
        if value & _RESET:
            self.reset()
            return
        if value & _UPDATE_ALL:
            self._update((1 << DAC_CHANNELS) - 1)

    def write_UPDATE(self, value: int) -> None:
        mask = value & ((1 << DAC_CHANNELS) - 1)
        if mask:
            self._update(mask)

    def describe(self) -> dict[str, Any]:
        return {
            "type": self.TYPE,
            "id": f"0x{DAC_BOARD_ID:04X}",
            "channels": DAC_CHANNELS,
            "wired": len(self.wiring),
            "settling_us": self.settling_time_ns / 1000,
        }

    # --- lanes (batched lockstep, hal.lanes) ---------------------------------------------
    @classmethod
    def from_lanes(cls, boards: Sequence[Any], crate: Any) -> DacBoard:
        """One board in lane mode holding the B scalar ``boards`` (lane order), for the lane
        crate ``crate`` (which installs it). Registers, offset/gain errors, rails and output
        volts become lane values; the wiring and the settling time must be the same in every
        lane (one clock: the settling events are the same instants), and so must the strobe
        history (which lockstep gives; ``Crate.from_lanes`` stacks crates with no event queued,
        so no output is settling then). Makes no bus cycle and drives no net
        (``Signals.from_lanes`` stacked them)."""
        first = boards[0]
        for b in boards:
            if type(b) is not cls:
                raise NotImplementedError(f"{first.name}: a {type(b).__name__} cannot be a lane of a {cls.__name__}")
            if b.faulted:
                raise NotImplementedError(f"{b.name}: a board with an injected fault runs scalar")
            if b.wiring != first.wiring or b.settling_time_ns != first.settling_time_ns:
                raise NotImplementedError(f"{first.name}: the lanes' boards differ in wiring or settling time")
            if (b._gen, [s[0] for s in b._step]) != (first._gen, [s[0] for s in first._step]):
                raise NotImplementedError(f"{first.name}: the lanes' boards were strobed at different times")
        obj = cls(first.name, wiring=first.wiring, settling_time_ns=first.settling_time_ns)
        obj.offset_v = tuple(stack([b.offset_v[ch] for b in boards]) for ch in range(DAC_CHANNELS))
        obj.gain_error = tuple(stack([b.gain_error[ch] for b in boards]) for ch in range(DAC_CHANNELS))
        obj.rail_v = stack([b.rail_v for b in boards])
        obj._stack_regs(boards)
        obj._step = [(first._step[ch][0], stack([b._step[ch][1] for b in boards]),
                      stack([b._step[ch][2] for b in boards])) for ch in range(DAC_CHANNELS)]
        obj._gen = list(first._gen)
        obj.updates = stack([b.updates for b in boards])
        for name in ("attach", "_analog", "read_CSR", "write_CSR", "write_UPDATE", "inject"):
            setattr(obj, name, getattr(obj, "_lane_" + name.lstrip("_")))
        return obj

    def _lane_attach(self, crate: Backplane) -> None:
        RegisterBoard.attach(self, crate)  # the steps and the nets are the stacked scalar ones

    def _lane_analog(self, ch: int, code: LaneValue) -> LaneValue:
        v = ideal_volts(code) * (1.0 + self.gain_error[ch]) + self.offset_v[ch]
        rail = self.rail_v
        if not isinstance(v, np.ndarray) and not isinstance(rail, np.ndarray):
            return min(max(v, -rail), rail)
        v = np.where(-rail > v, -rail, v)  # max(v, -rail): a NaN stays, as max() leaves it
        return np.where(rail < v, rail, v)  # min(·, rail)

    def _lane_read_CSR(self) -> LaneValue:
        now, st = self.now_ns, self.settling_time_ns
        settling: Any = False
        for t0, vs, vf in self._step:
            if now - t0 < st:
                settling = settling | (vs != vf)
        if isinstance(settling, np.ndarray):
            return np.where(settling, _SETTLING, 0)
        return _SETTLING if settling else 0

    def _lane_write_CSR(self, value: LaneValue) -> None:
        DacBoard.write_CSR(self, _uniform(value, self.name, "CSR"))

    def _lane_write_UPDATE(self, value: LaneValue) -> None:
        DacBoard.write_UPDATE(self, _uniform(value, self.name, "UPDATE"))

    def _lane_inject(self, name: str, **params: Any) -> None:
        raise NotImplementedError(f"{self.name}: faults are not injected into lanes (such runs go scalar)")


def ideal_volts(code: int) -> float:
    """The ideal output of a 12-bit offset-binary ``code``: 0x800 is 0 V, one code 20 V/4096
    (0x000 → −10 V, 0xFFF → +9.99512 V)."""
    return (code - DAC_POWER_UP_CODE) * _LSB_V


def _uniform(value: LaneValue, board: str, reg: str) -> int:
    """A strobe/control word that must be the same in every lane (the strobes' instants are the
    lanes' common settling events): the word itself."""
    if isinstance(value, np.ndarray):
        v0 = value.flat[0]
        if (value != v0).any():
            raise NotImplementedError(f"{board}.{reg}: a write that differs between lanes (one clock for all lanes)")
        return int(v0)
    return value  # type: ignore[no-any-return]


def _data_writer(ch: int):
    def write(self: DacBoard, value: int) -> None:
        self.regs[_DATA[ch]] = value & CODE_MAX  # 12 bits; bits 15:12 ignored, read 0

    write.__name__ = f"write_DATA{ch}"
    return write


for _ch in range(DAC_CHANNELS):  # write_DATA0..write_DATA7
    setattr(DacBoard, f"write_DATA{_ch}", _data_writer(_ch))


def dac_factory(name: str, cfg: ConfigTable, ctx: BuildContext) -> DacBoard:
    """Crate-file factory for ``type = "dac"``.

    Keys: ``wiring`` (table channel → net), ``offset_v`` and ``gain_error`` (8 numbers each),
    ``settling_time_us``.
    """
    return DacBoard(
        name,
        wiring=wiring_from_config(cfg, DAC_CHANNELS),
        offset_v=cfg.floats("offset_v", None, length=DAC_CHANNELS) if "offset_v" in cfg else None,
        gain_error=cfg.floats("gain_error", None, length=DAC_CHANNELS) if "gain_error" in cfg else None,
        settling_time_ns=round(cfg.get_float("settling_time_us", DEFAULT_SETTLING_NS / 1000, min=0.0, max=10_000.0)
                               * 1000),
    )
