"""Emulated VMIC VMIVME-2536 (32 optically coupled inputs, 32 outputs), written from its spec,
docs/boards/vmivme2536.md.

A second reading of the doc, independent of the driver: the register map, the line names and the
CSR bits below are this module's own, written from the doc's tables (nothing is imported from
``hal.pio``), so a wrong offset, bit or width in the driver's map shows up as a driver/board
disagreement instead of being copied here.

Wiring: each line (``"IN0"``..``"IN31"``, ``"OUT0"``..``"OUT31"``) may be wired to a digital
net. An output drives its net high while the outputs are active (CSR bit 14) and its latch bit
is 1, low otherwise; an input reads its net while the inputs are active (CSR bit 13), and 0
while they are not. An input wired to an output's net reads what that output really drives (a
loopback). No interrupt, no timer; switching is immediate (the sources give no time).

Faults: ``line_stuck(line="OUT0", level=True)`` — the wire is held at ``level``: a stuck output
drives the stuck level onto its net (``OUTPUT`` still reads the latch), a stuck input reads it.

Lanes (batched lockstep, :mod:`hal.lanes`): :meth:`Vmi2536Board.from_lanes` stacks B boards
(wired alike) into one whose registers are lane values; each output drives its net with a bool
per lane and ``INPUT`` reads each lane's nets. Injected faults are refused (such runs go scalar).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, ClassVar

import numpy as np

from emulators.board import RegisterBoard
from hal.lanes import LaneSet, LaneValue
from hal.vme.registers import Access, Field, Register, RegisterMap
from hal.vme.types import AddressSpace, Width

#: docs/boards/vmivme2536.md, "Registers", row by row (offset, register, width, access, reset, bits)
VMI2536_BOARD_MAP = RegisterMap("vmivme-2536", 0x10, AddressSpace.A16, (
    Register("BID", 0x00, Width.D16, Access.RO),
    Register("CSR", 0x02, Width.D16, Access.RW, reset=0x0000,
             fields=(Field("led_off", 15, 1, "fail LED off"), Field("outputs_on", 14, 1, "outputs active"),
                     Field("inputs_on", 13, 1, "inputs active"))),
    Register("INPUT", 0x04, Width.D32, Access.RO, reset=0x0000_0000),
    Register("OUTPUT", 0x08, Width.D32, Access.RW, reset=0x0000_0000),
))

_LED_OFF, _OUTPUTS_ON, _INPUTS_ON = 0x8000, 0x4000, 0x2000
_CSR_BITS = _LED_OFF | _OUTPUTS_ON | _INPUTS_ON  #: bits 12:0 are ignored on write and read 0
#: BID answered when the crate file states none: a stand-in (the real value is not published)
DEFAULT_BOARD_ID = 0x2536
_N = 32


def _line(name: str) -> tuple[bool, int]:
    """(is an output, channel) of ``"IN0"``..``"IN31"`` / ``"OUT0"``..``"OUT31"``; ``ValueError`` else."""
    s = name.strip().upper()
    for prefix, is_out in (("OUT", True), ("IN", False)):
        digits = s.removeprefix(prefix)
        if digits != s and digits.isdigit() and str(int(digits)) == digits and int(digits) < _N:
            return is_out, int(digits)
    raise ValueError(f"{name!r} is not a VMIVME-2536 line; expected IN0..IN31 or OUT0..OUT31")


class Vmi2536Board(RegisterBoard):
    """32 inputs, 32 outputs, activated by CSR; no interrupt.

    Args:
        name: board name in the crate.
        lines: line → net name (``{"OUT0": "j1.amp_enable", "IN0": "j1.amp_fault"}``).
        board_id: what ``BID`` answers.
    """

    TYPE = "vmivme-2536"
    REGMAP = VMI2536_BOARD_MAP
    VENDOR, MODEL, DOCUMENT = "VMIC", "VMIVME-2536", "docs/boards/vmivme2536.md"
    FAULTS: ClassVar[dict[str, str]] = {
        "line_stuck": "line=INn|OUTn, level=bool: the wire is held at level (board and net cannot move it)",
    }
    _wired_inputs: tuple[tuple[int, str], ...]  #: in lane mode only (from_lanes): (channel, net) in order

    def __init__(self, name: str, lines: dict[str, str] | None = None, board_id: int = DEFAULT_BOARD_ID) -> None:
        if not 0 <= board_id <= 0xFFFF:
            raise ValueError(f"board_id {board_id} is not a 16-bit value")
        self.board_id = board_id
        self.outputs: dict[int, str] = {}
        self.inputs: dict[int, str] = {}
        for pin, net in (lines or {}).items():
            is_out, ch = _line(pin)
            (self.outputs if is_out else self.inputs)[ch] = str(net)
        super().__init__(name)

    # --- crate hooks ---------------------------------------------------------------------
    def attach(self, crate) -> None:
        super().attach(crate)
        self._drive_outputs()

    def reset(self) -> None:
        super().reset()
        self._drive_outputs()

    def describe(self) -> dict[str, Any]:
        wired = {f"OUT{ch}": n for ch, n in sorted(self.outputs.items())}
        wired.update({f"IN{ch}": n for ch, n in sorted(self.inputs.items())})
        return {"type": self.TYPE, "vendor": self.VENDOR, "model": self.MODEL, "document": self.DOCUMENT,
                "lines": wired}

    # --- registers -----------------------------------------------------------------------
    def read_BID(self) -> int:
        return self.board_id

    def write_CSR(self, value: int) -> None:
        self.regs["CSR"] = value & _CSR_BITS
        self._drive_outputs()

    def write_OUTPUT(self, value: int) -> None:
        self.regs["OUTPUT"] = value & 0xFFFF_FFFF
        self._drive_outputs()

    def read_INPUT(self) -> int:
        if not self.regs["CSR"] & _INPUTS_ON:
            return 0
        value = 0
        for ch in range(_N):
            if self.input_level(ch):
                value |= 1 << ch
        return value

    # --- the wires -----------------------------------------------------------------------
    def _stuck(self, is_out: bool, ch: int) -> bool | None:
        f = self.fault("line_stuck")
        if f is None or _line(str(f.get("line", ""))) != (is_out, ch):
            return None
        return bool(f.get("level", False))

    def output_level(self, ch: int) -> bool:
        """The level output ``ch`` drives onto its wire."""
        if self.faulted:
            stuck = self._stuck(True, ch)
            if stuck is not None:
                return stuck
        return bool(self.regs["CSR"] & _OUTPUTS_ON) and bool(self.regs["OUTPUT"] >> ch & 1)

    def input_level(self, ch: int) -> bool:
        """The level on input ``ch``'s wire (unwired: 0)."""
        if self.faulted:
            stuck = self._stuck(False, ch)
            if stuck is not None:
                return stuck
        net = self.inputs.get(ch)
        if net is None or self.crate is None:
            return False
        return self.crate.signals.get_digital(net)

    def _drive_outputs(self) -> None:
        if self.crate is None:
            return
        for ch, net in self.outputs.items():
            self.crate.signals.set_digital(net, self.output_level(ch))

    # --- lanes (batched lockstep, hal.lanes) ---------------------------------------------
    @classmethod
    def from_lanes(cls, boards: Sequence[Any], crate: Any) -> Vmi2536Board:
        """One board in lane mode holding the B scalar ``boards`` (lane order), for the lane
        crate ``crate`` (``crate.lanes``), which installs it. The wiring and ``BID`` must be the
        same in every lane; the registers are stacked. No bus cycle; installing drives each
        output's net with the level it already holds (``Signals.from_lanes`` stacked the nets)."""
        first = boards[0]
        lanes = getattr(crate, "lanes", None)
        if not isinstance(lanes, LaneSet):
            raise ValueError(f"{first.name}: a board in lanes needs a crate of lanes (crate.lanes)")
        for b in boards:
            if type(b) is not cls:
                raise NotImplementedError(f"{first.name}: a {type(b).__name__} cannot be a lane of a {cls.__name__}")
            if b.faulted:
                raise NotImplementedError(f"{b.name}: a board with an injected fault runs scalar")
            if (b.outputs, b.inputs, b.board_id) != (first.outputs, first.inputs, first.board_id):
                raise NotImplementedError(f"{first.name}: the lanes' boards are wired differently")
        lines = {f"OUT{ch}": net for ch, net in first.outputs.items()}
        lines.update({f"IN{ch}": net for ch, net in first.inputs.items()})
        obj = cls(first.name, lines=lines, board_id=first.board_id)
        obj._stack_regs(boards)
        #: the wired inputs in channel order (INPUT is assembled from them)
        obj._wired_inputs = tuple(sorted(obj.inputs.items()))
        for name in ("read_INPUT", "output_level", "input_level", "_drive_outputs", "inject"):
            setattr(obj, name, getattr(obj, "_lane_" + name.lstrip("_")))
        return obj

    def _lane_read_INPUT(self) -> LaneValue:
        # read_INPUT per lane: a wired input's bit is its net's level (a bool per lane), unwired
        # inputs read 0, and every bit reads 0 in a lane whose inputs are off
        value: LaneValue = 0
        if self.crate is not None:
            digital = self.crate.signals.digital
            for ch, net in self._wired_inputs:
                level = digital.get(net, False)
                if isinstance(level, np.ndarray):
                    value = value | (level.astype(np.int64) << ch)
                elif level:
                    value = value | (1 << ch)
        on = self.regs["CSR"] & _INPUTS_ON
        if isinstance(on, np.ndarray):
            return np.where(on != 0, value, 0)
        return value if on else 0

    def _lane_output_level(self, ch: int) -> LaneValue:
        return (self.regs["CSR"] & _OUTPUTS_ON != 0) & ((self.regs["OUTPUT"] >> ch) & 1 != 0)

    def _lane_input_level(self, ch: int) -> LaneValue:
        net = self.inputs.get(ch)
        if net is None or self.crate is None:
            return False
        return self.crate.signals.get_digital(net)

    def _lane_drive_outputs(self) -> None:
        if self.crate is None:
            return
        signals = self.crate.signals
        for ch, net in self.outputs.items():
            signals.set_digital(net, self.output_level(ch))

    def _lane_inject(self, name: str, **params: Any) -> None:
        raise NotImplementedError(f"{self.name}: faults are not injected into lanes (such runs go scalar)")

    # --- faults --------------------------------------------------------------------------
    def _fault_changed(self, name: str) -> None:
        if name == "line_stuck":
            f = self.fault("line_stuck")
            if f is not None:
                try:
                    _line(str(f.get("line", "")))
                except ValueError:
                    self.clear_fault("line_stuck")
                    raise
            self._drive_outputs()


def vmivme2536_from_config(name: str, cfg, ctx) -> Vmi2536Board:
    """Crate-file factory (``type = "vmivme-2536"``)::

        [[crate.board]]
        type = "vmivme-2536"
        name = "dio0"
        space = "A16"
        base = 0xFF00
        board_id = 0x2536          # optional
        lines = { OUT0 = "j1.amp_enable", IN0 = "j1.amp_fault" }
    """
    lines: dict[str, str] = {}
    if "lines" in cfg:
        tbl = cfg.table("lines")
        for pin in list(tbl.keys()):
            net = tbl.get_str(pin)
            try:
                _line(pin)
            except ValueError:
                raise tbl.error(pin, "a VMIVME-2536 line IN0..IN31 or OUT0..OUT31", pin) from None
            lines[pin.upper()] = net
    board_id = cfg.get_int("board_id", min=0, max=0xFFFF) if "board_id" in cfg else DEFAULT_BOARD_ID
    return Vmi2536Board(name, lines=lines, board_id=board_id)
