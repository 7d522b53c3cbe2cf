"""The vmehil CAN message set, generated once into ``vmehil.dbc`` (shipped with the package).

The DBC file is the single source of truth at run time: the codec reads every scale, offset,
length and range from it (:mod:`emulators.can.codec`). This module only *writes* it, so the
layout is reviewable as Python; ``tests/emulators/can/test_codec.py`` checks that the shipped file equals
the generator's output. Regenerate with ``python -m emulators.can.dbc``.

Frame identifiers (11-bit; lower = higher bus priority). ``j`` is the joint index 0..31.

======  ==================  =====  =========================  =====================================
ID      message             bytes  sender → receiver          content
======  ==================  =====  =========================  =====================================
0x080   SYNC                24 FD  controller → plant         tick, period, delay, watchdog line
0x081   CONTROL             8      controller → plant         reset request (seed), joint count
0x100+j CMD_Jjj             12 FD  controller → plant         amplifier command / enable / reset, PWM, brake
0x200+j SENS_Jjj            24 FD  plant → controller         pot, tach, current monitor, encoder, fault
0x280   PLANT_STATUS        16 FD  plant → controller         end of answer: tick echo, counters, watchdog
0x300+j TRUTH_Jjj           32 FD  plant → controller         ground truth (float64), reports only
0x701   HEARTBEAT_CONTROLLER 8     controller → all           state, boot id, counter
0x702   HEARTBEAT_PLANT     12 FD  plant → all                state, boot id, counter, amplifier state
0x703   PLANT_SESSION       8      plant → all                session owner and number, refused frames
======  ==================  =====  =========================  =====================================
"""

from __future__ import annotations

from collections import OrderedDict
from pathlib import Path
from typing import cast

import cantools
from cantools.database.can import Database, Message, Node, Signal
from cantools.database.conversion import BaseConversion
from cantools.typechecking import Choices

DBC_PATH = Path(__file__).with_name("vmehil.dbc")

MAX_JOINTS = 32
ID_SYNC = 0x080
ID_CONTROL = 0x081
ID_CMD = 0x100
ID_SENS = 0x200
ID_STATUS = 0x280
ID_TRUTH = 0x300
ID_HEARTBEAT_CONTROLLER = 0x701
ID_HEARTBEAT_PLANT = 0x702
ID_SESSION = 0x703
# Unit controllers and their coordinator (docs/melmalec.md): a bus of their own (the unit bus),
# where the coordinator answers the units with SENS/TRUTH frames of their joints and the units
# send it CMD frames of theirs, as a controller and the plant node do on the plant bus.
ID_UNIT_STOP = 0x070
ID_UNIT_START = 0x071
ID_UNIT_SYNC = 0x090
ID_UNIT_POS = 0x091
ID_UNIT_TIMING = 0x092
ID_UNIT_ANSWER = 0x290
ID_UNIT_HEARTBEAT = 0x710
UNIT_IDS = (ID_UNIT_STOP, ID_UNIT_START, ID_UNIT_SYNC, ID_UNIT_POS, ID_UNIT_TIMING, ID_UNIT_ANSWER, ID_UNIT_HEARTBEAT)
#: UNIT_TIMING's per-tick figures (seconds, 1 µs LSB): what a unit's real-time runner measured
UNIT_TIMING_FIGURES = ("ComputeP50", "ComputeP99", "ComputeMax", "LatenessP50", "LatenessP99", "LatenessMax",
                       "ControllerP50", "ControllerP99")

VOLT_LSB = 2e-6  # V per bit of every analog voltage on the wire (24-bit signed: ±16.78 V)
DUTY_LSB = 1e-6  # PWM duty per bit (20-bit unsigned)

CONTROLLER = "CONTROLLER"
PLANT = "PLANT"


def _sig(name: str, start: int, length: int, *, signed: bool = False, scale: float = 1, offset: float = 0,
         minimum: float | None = None, maximum: float | None = None, unit: str | None = None,
         comment: str | None = None, is_float: bool = False, choices: dict[int, str] | None = None,
         receiver: str = PLANT) -> Signal:
    # cantools annotates ``choices`` as an OrderedDict (its parser's type); same items, same order
    named: Choices | None = None if choices is None else OrderedDict(choices)
    return Signal(name, start, length, "little_endian", is_signed=signed,
                  conversion=BaseConversion.factory(scale, offset, named, is_float),
                  minimum=minimum, maximum=maximum, unit=unit, comment=comment, receivers=[receiver])


def _volts(name: str, start: int, comment: str, receiver: str) -> Signal:
    return _sig(name, start, 24, signed=True, scale=VOLT_LSB, minimum=-(2**23) * VOLT_LSB,
                maximum=(2**23 - 1) * VOLT_LSB, unit="V", comment=comment, receiver=receiver)


def _bit(name: str, start: int, comment: str, receiver: str) -> Signal:
    return _sig(name, start, 1, minimum=0, maximum=1, comment=comment, receiver=receiver)


NODE_STATES = {0: "BOOT", 1: "READY", 2: "RUNNING", 3: "STOPPED", 4: "FAULT"}
#: UNIT_STOP.Cause and UNIT_ANSWER.Stop: why every unit stops
UNIT_STOP_CAUSES = {0: "NONE", 1: "UNIT_STOPPED", 2: "UNIT_LOST", 3: "COORDINATOR_END", 4: "REFUSED_RIG",
                    5: "REFUSED_LATE", 6: "COORDINATOR_STOPPED", 7: "ANSWER_INCOMPLETE", 8: "PLANT_LOST",
                    9: "REFUSED_DUPLICATE", 10: "RUN_REFUSED"}
COORDINATOR = "COORDINATOR"
UNIT = "UNIT"
#: HEARTBEAT_PLANT.OffCause: the bits of emulators.plant.amplifier.WATCHDOG_EXPIRED / _COMMAND_TIMEOUT
OFF_CAUSES = {0: "NONE", 1: "WATCHDOG", 2: "COMMAND_TIMEOUT", 3: "WATCHDOG_AND_COMMAND_TIMEOUT"}
#: CONTROL.Command
CONTROL_NONE, CONTROL_RESET, CONTROL_END = 0, 1, 2
CONTROL_COMMANDS = {CONTROL_NONE: "NONE", CONTROL_RESET: "RESET", CONTROL_END: "END"}


def build_database(max_joints: int = MAX_JOINTS) -> Database:
    """The message set as a cantools :class:`Database`."""
    C, P = CONTROLLER, PLANT
    msgs: list[Message] = [
        Message(ID_SYNC, "SYNC", 24, [
            _sig("Tick", 0, 32, maximum=2**32 - 1, minimum=0, comment="exchange number (0 = priming exchange)"),
            _sig("PeriodS", 32, 64, is_float=True, unit="s", minimum=0, maximum=1,
                 comment="servo period the plant advances (float64, exact)"),
            _sig("DelayS", 96, 64, is_float=True, unit="s", minimum=0, maximum=1,
                 comment="computation delay: the previous command holds this long (float64, exact)"),
            _sig("Seq", 160, 8, minimum=0, maximum=255, comment="Tick mod 256"),
            _bit("Watchdog", 168, "amplifier enable-watchdog (charge-pump) line over the coming period", P),
            _sig("BootId", 176, 16, minimum=0, maximum=65535,
                 comment="sender's controller boot id: the node steps only its session owner's SYNC"),
        ], senders=[C], is_fd=True, comment="Lockstep: advance one servo period and answer."),
        Message(ID_CONTROL, "CONTROL", 8, [
            _sig("Command", 0, 8, minimum=0, maximum=255, choices=dict(CONTROL_COMMANDS),
                 comment="RESET: rebuild the plant with Seed, start at rest and open a session for BootId; "
                         "END: the session's owner closes it (amplifiers idle)"),
            _sig("Seed", 8, 32, minimum=0, maximum=2**32 - 1, comment="seed of every plant noise source"),
            _sig("NJoints", 40, 8, minimum=0, maximum=255, comment="joints the controller expects"),
            _sig("BootId", 48, 16, minimum=0, maximum=65535, comment="controller boot identifier (session owner)"),
        ], senders=[C]),
        Message(ID_STATUS, "PLANT_STATUS", 16, [
            _sig("Tick", 0, 32, minimum=0, maximum=2**32 - 1, receiver=C,
                 comment="tick answered (lockstep: SYNC Tick; free-running: plant step count); "
                         "with ResetAck: the BootId of the RESET acknowledged"),
            _sig("BootId", 32, 16, minimum=0, maximum=65535, receiver=C, comment="plant boot identifier"),
            _sig("NJoints", 48, 8, minimum=0, maximum=255, receiver=C),
            _sig("FreeRunning", 56, 1, minimum=0, maximum=1, receiver=C),
            _sig("StepError", 57, 1, minimum=0, maximum=1, receiver=C, comment="the plant rejected the step"),
            _sig("ResetAck", 58, 1, minimum=0, maximum=1, receiver=C, comment="answer to a CONTROL RESET"),
            _sig("WatchdogTripped", 59, 1, minimum=0, maximum=1, receiver=C,
                 comment="an amplifier is latched off by the enable watchdog or the command timeout"),
            _sig("Session", 60, 4, minimum=0, maximum=15, receiver=C,
                 comment="session this answer belongs to (1..15, one per accepted RESET; 0: none)"),
            _sig("MissingCmd", 64, 16, minimum=0, maximum=65535, receiver=C,
                 comment="command frames missing at a step (held), total, saturating"),
            _sig("Dropped", 80, 16, minimum=0, maximum=65535, receiver=C,
                 comment="malformed / unknown / late frames dropped, total, saturating"),
            _sig("SeqJumps", 96, 16, minimum=0, maximum=65535, receiver=C,
                 comment="SYNC ticks that were not the previous + 1, total, saturating"),
            _sig("Steps", 112, 16, minimum=0, maximum=65535, receiver=C, comment="steps since reset, mod 65536"),
        ], senders=[P], is_fd=True, comment="Ends the plant's answer to one tick."),
    ]
    for node, fid in ((C, ID_HEARTBEAT_CONTROLLER), (P, ID_HEARTBEAT_PLANT)):
        other = P if node == C else C
        signals = [
            _sig("State", 0, 8, minimum=0, maximum=255, choices=dict(NODE_STATES), receiver=other),
            _sig("BootId", 8, 16, minimum=0, maximum=65535, receiver=other),
            _sig("Counter", 24, 8, minimum=0, maximum=255, receiver=other),
            _sig("Tick", 32, 32, minimum=0, maximum=2**32 - 1, receiver=other, comment="last tick handled"),
        ]
        comment = "Sent every 100 ms (wall clock)."
        if node == P:  # the amplifier side's state: readable while no tick is answered (a dead controller)
            signals += [
                _sig("AmpsEnabled", 64, 8, minimum=0, maximum=255, receiver=C,
                     comment="amplifiers whose output stage is on"),
                _sig("WatchdogTripped", 72, 8, minimum=0, maximum=255, receiver=C,
                     comment="amplifiers latched off by the enable watchdog or the command timeout"),
                _sig("OffCause", 80, 8, minimum=0, maximum=255, receiver=C, choices=dict(OFF_CAUSES),
                     comment="why they are latched off: 1 watchdog line stopped, 2 command timeout (bits)"),
                _sig("CommandTimeout", 88, 1, minimum=0, maximum=1, receiver=C,
                     comment="no CONTROL/SYNC for longer than the node's command timeout"),
            ]
            comment = "Sent every 100 ms (wall clock) and at once when the amplifier state changes."
        msgs.append(Message(fid, f"HEARTBEAT_{node}", 8 if node == C else 12, signals, senders=[node],
                            is_fd=node == P, comment=comment))
    msgs.append(Message(ID_SESSION, "PLANT_SESSION", 8, [
        _sig("Owner", 0, 16, minimum=0, maximum=65535, receiver=C,
             comment="boot id of the controller whose session runs (with Active)"),
        _sig("Session", 16, 4, minimum=0, maximum=15, receiver=C, comment="its number, as in PLANT_STATUS.Session"),
        _sig("Active", 20, 1, minimum=0, maximum=1, receiver=C,
             comment="a session runs: RESET, CONTROL, SYNC and CMD from other boot ids are refused"),
        _sig("Open", 21, 1, minimum=0, maximum=1, receiver=C,
             comment="a RESET from another boot id would be accepted now (no session, or its owner silent)"),
        _sig("Refused", 24, 16, minimum=0, maximum=65535, receiver=C,
             comment="frames from controllers other than the owner refused, total, saturating"),
        _sig("RefusedBoot", 40, 16, minimum=0, maximum=65535, receiver=C,
             comment="boot id of the last controller refused"),
    ], senders=[P], comment="Sent with every HEARTBEAT_PLANT and at once on a session change or a refused RESET."))
    msgs += _unit_messages()
    for j in range(max_joints):
        msgs.append(Message(ID_CMD + j, f"CMD_J{j:02d}", 12, [
            _volts("AmpCommand", 0, "transconductance amplifier input", P),
            _sig("PwmDuty", 24, 20, scale=DUTY_LSB, minimum=0, maximum=1, comment="H-bridge PWM duty 0..1"),
            _bit("AmpEnable", 44, "amplifier enable line", P),
            _bit("FaultReset", 45, "amplifier fault reset line (rising edge clears)", P),
            _bit("PwmDirection", 46, "H-bridge direction (1 = positive)", P),
            _bit("Brake", 47, "H-bridge brake (winding shorted)", P),
            _sig("Seq", 48, 8, minimum=0, maximum=255, comment="Tick mod 256 of the SYNC this belongs to"),
            _sig("BootIdLow", 56, 8, minimum=0, maximum=255,
                 comment="low byte of the sender's controller boot id: the node takes only its session owner's"),
            _bit("HoldingBrake", 64, "holding brake line (1 = energised = released; 0 = the brake holds)", P),
        ], senders=[C], is_fd=True, comment=f"Joint {j}: commands held over the coming servo period."))
        msgs.append(Message(ID_SENS + j, f"SENS_J{j:02d}", 32, [
            _volts("PotVoltage", 0, "joint potentiometer wiper at the sampling instant", C),
            _volts("TachVoltage", 24, "tachometer at the sampling instant (0 without one)", C),
            _volts("CurrentMonitor", 48, "amplifier current monitor at the sampling instant", C),
            _sig("EncoderCounts", 72, 24, signed=True, minimum=-(2**23), maximum=2**23 - 1, unit="counts",
                 receiver=C, comment="net decoded x4 counts during the period"),
            _sig("EncoderIllegal", 96, 16, minimum=0, maximum=65535, receiver=C,
                 comment="illegal transitions sampled during the period (saturating)"),
            _sig("EncoderPhase", 112, 2, minimum=0, maximum=3, receiver=C, comment="quadrature state at the end"),
            _bit("AmpFault", 114, "amplifier fault line (latched)", C),
            _bit("Switching", 115, "H-bridge switching during the period", C),
            _sig("IndexCount", 116, 4, minimum=0, maximum=15, receiver=C,
                 comment="index pulses during the period (saturating)"),
            _sig("IndexFirst", 120, 24, signed=True, minimum=-(2**23), maximum=2**23 - 1, unit="counts",
                 receiver=C, comment="count offset of the first index pulse"),
            _sig("IndexLast", 144, 24, signed=True, minimum=-(2**23), maximum=2**23 - 1, unit="counts",
                 receiver=C, comment="count offset of the last index pulse"),
            _sig("Seq", 168, 8, minimum=0, maximum=255, receiver=C, comment="Tick mod 256 answered"),
            _sig("EncoderTotal", 176, 32, minimum=0, maximum=2**32 - 1, unit="counts", receiver=C,
                 comment="net x4 counts since the session's start, mod 2^32 (HasTotal): a receiver that "
                         "missed answers recovers their counts from it"),
            _bit("HasTotal", 208, "EncoderTotal is kept by the sender", C),
            _sig("BootIdLow", 216, 8, minimum=0, maximum=255, receiver=C,
                 comment="sender's boot id, low byte: a receiver takes its session's only"),
        ], senders=[P], is_fd=True, comment=f"Joint {j}: sensors at the end of the period."))
        msgs.append(Message(ID_TRUTH + j, f"TRUTH_J{j:02d}", 32, [
            _sig("ThetaJoint", 0, 64, is_float=True, unit="rad", receiver=C),
            _sig("OmegaJoint", 64, 64, is_float=True, unit="rad/s", receiver=C),
            _sig("CurrentA", 128, 64, is_float=True, unit="A", receiver=C),
            _sig("FrictionNm", 192, 64, is_float=True, unit="Nm", receiver=C),
        ], senders=[P], is_fd=True, comment=f"Joint {j}: ground truth for reports (never for the servo)."))
    msgs.sort(key=lambda m: m.frame_id)
    # A CAN FD bus: the DBC writer marks FD messages (VFrameFormat) only when the database
    # carries the BusType attribute, which is easiest to give it by parsing a header.
    # a DBC string always loads as a CAN database (load_string's return type also admits CDD)
    db = cast(Database, cantools.database.load_string(_FD_HEADER, database_format="dbc"))
    db.messages.extend(msgs)
    db.nodes.extend([Node(CONTROLLER), Node(PLANT), Node(COORDINATOR), Node(UNIT)])
    db.version = "vmehil-1"
    db.refresh()
    return db


def _unit_messages() -> list[Message]:
    """The unit bus's own frames (CMD/SENS/TRUTH of the joints are the plant bus's, reused)."""
    K, U = COORDINATOR, UNIT
    boot = _sig("BootId", 48, 16, minimum=0, maximum=65535, comment="sender's boot id")
    return [
        Message(ID_UNIT_STOP, "UNIT_STOP", 12, [
            _sig("Cause", 0, 8, minimum=0, maximum=255, choices=dict(UNIT_STOP_CAUSES), receiver=U),
            _sig("Unit", 8, 8, minimum=0, maximum=255, receiver=U,
                 comment="the unit it concerns (255: every unit)"),
            _sig("Exchange", 16, 32, minimum=0, maximum=2**32 - 1, receiver=U, comment="the exchange it is sent at"),
            boot,
            _sig("UnitBootId", 64, 16, minimum=0, maximum=65535, receiver=U,
                 comment="before the start: the boot id of the unit refused (from its heartbeat)"),
        ], senders=[K], is_fd=True, comment="Stop: every unit (or the one named, refused) safe-stops at once."),
        Message(ID_UNIT_START, "UNIT_START", 64, [
            _sig("Seed", 0, 32, minimum=0, maximum=2**32 - 1, receiver=U, comment="seed of every noise source"),
            _sig("NTicks", 32, 32, minimum=0, maximum=2**32 - 1, receiver=U, comment="ticks to run"),
            _sig("RigDigest", 64, 32, minimum=0, maximum=2**32 - 1, receiver=U,
                 comment="CRC-32 of the rig file: a unit with another refuses to start"),
            _sig("MotionDigest", 96, 32, minimum=0, maximum=2**32 - 1, receiver=U,
                 comment="CRC-32 of the motion file (0: the default demo)"),
            _sig("NUnits", 128, 8, minimum=0, maximum=255, receiver=U),
            _sig("SwitchOff", 136, 2, minimum=0, maximum=3, receiver=U,
                 comment="integrator switch-off: 0 as the rig file, 1 off, 2 on"),
            _sig("GainsSet", 138, 1, minimum=0, maximum=1, receiver=U, comment="Kp..Kvi override the rig's"),
            _sig("FreeRunning", 139, 1, minimum=0, maximum=1, receiver=U,
                 comment="1: every unit and the plant step on their own wall clock (0: lockstep)"),
            _sig("BootId", 144, 16, minimum=0, maximum=65535, receiver=U, comment="coordinator boot id"),
            _sig("StaleTicks", 160, 8, minimum=0, maximum=255, receiver=U,
                 comment="free-running: exchanges without a fresh answer before a unit safe-stops"),
            *[_sig(name, 192 + 64 * i, 64, is_float=True, receiver=U, comment="gain override (float64, exact)")
              for i, name in enumerate(("Kp", "Kpi", "Kv", "Kvi"))],
            _sig("Unit", 448, 8, minimum=0, maximum=255, receiver=U, comment="the unit this start is for"),
            _sig("UnitBootId", 456, 16, minimum=0, maximum=65535, receiver=U,
                 comment="that unit's boot id, from its heartbeat: a unit starts only on its own"),
        ], senders=[K], is_fd=True,
            comment="Start, one per unit: every unit builds its boards and runs NTicks (lockstep or free-running)."),
        Message(ID_UNIT_SYNC, "UNIT_SYNC", 8, [
            _sig("Exchange", 0, 32, minimum=0, maximum=2**32 - 1, receiver=K,
                 comment="the unit's exchange number (0 = power-up); its CMD frames precede it"),
            _sig("Unit", 32, 8, minimum=0, maximum=255, receiver=K),
            _bit("Stopped", 40, "the unit's loop has stopped (its commands are the safe outputs)", K),
            _bit("Watchdog", 41, "the enable-watchdog line, from the unit that drives it", K),
            _bit("Left", 42, "the unit's run has ended: the plant no longer waits for it", K),
            boot,
        ], senders=[U], comment="Unit status with each exchange: the plant steps once every unit's is in."),
        Message(ID_UNIT_POS, "UNIT_POS", 48, [
            _sig("Unit", 0, 8, minimum=0, maximum=255, receiver=U),
            *[_sig(f"Theta{i}", 64 + 64 * i, 64, is_float=True, unit="rad", receiver=U,
                   comment="measured start of the unit's joint i (float64, exact; NaN: none)") for i in range(4)],
            _sig("BootId", 320, 16, minimum=0, maximum=65535, receiver=U, comment="sender's boot id"),
        ], senders=[U], is_fd=True, comment="A unit's measured start: every unit plans the global motion from all."),
        Message(ID_UNIT_TIMING, "UNIT_TIMING", 48, [
            _sig("Unit", 0, 8, minimum=0, maximum=255, receiver=K),
            _bit("Realtime", 8, "the unit ran on the wall clock (0: no figures but Ticks)", K),
            _sig("Ticks", 16, 32, minimum=0, maximum=2**32 - 1, receiver=K, comment="ticks the unit ran"),
            _sig("Overruns", 48, 32, minimum=0, maximum=2**32 - 1, receiver=K,
                 comment="ticks that ended after the next tick's deadline"),
            *[_sig(name, 80 + 32 * i, 32, scale=1e-6, minimum=0, maximum=(2**32 - 1) * 1e-6, unit="s", receiver=K,
                   comment="per tick (p50/p99/max): compute = the whole tick, lateness = its start after the "
                           "deadline, controller = drivers + law")
              for i, name in enumerate(UNIT_TIMING_FIGURES)],
            _sig("BootId", 336, 16, minimum=0, maximum=65535, receiver=K, comment="sender's boot id"),
        ], senders=[U], is_fd=True, comment="A unit's real-time figures, sent once as it leaves the run."),
        Message(ID_UNIT_ANSWER, "UNIT_ANSWER", 12, [
            _sig("Exchange", 0, 32, minimum=0, maximum=2**32 - 1, receiver=U,
                 comment="the exchange answered (its SENS/TRUTH frames precede it)"),
            _sig("Stop", 32, 8, minimum=0, maximum=255, choices=dict(UNIT_STOP_CAUSES), receiver=U,
                 comment="every unit stops in this exchange: why (0: run on)"),
            _sig("StopUnit", 40, 8, minimum=0, maximum=255, receiver=U, comment="the unit that stopped or was lost"),
            boot,
            _sig("PlantStep", 64, 32, minimum=0, maximum=2**32 - 1, receiver=U,
                 comment="the plant's step whose values the answer carries (its time: PlantStep periods): "
                         "free-running, a step may be missed or answered twice"),
        ], senders=[K], is_fd=True, comment="Ends the coordinator's answer to one exchange."),
        Message(ID_UNIT_HEARTBEAT, "UNIT_HEARTBEAT", 16, [
            _sig("State", 0, 8, minimum=0, maximum=255, choices=dict(NODE_STATES), receiver=K),
            _sig("Unit", 8, 8, minimum=0, maximum=255, receiver=K),
            _sig("Counter", 16, 8, minimum=0, maximum=255, receiver=K),
            _sig("Exchange", 24, 32, minimum=0, maximum=2**32 - 1, receiver=K),
            _sig("RigDigest", 56, 32, minimum=0, maximum=2**32 - 1, receiver=K),
            _sig("BootId", 88, 16, minimum=0, maximum=65535, receiver=K),
        ], senders=[U], is_fd=True, comment="A unit's state: every 100 ms while it waits to start."),
    ]


_FD_HEADER = """VERSION "vmehil-1"
BS_:
BU_:
BA_DEF_ "BusType" STRING ;
BA_DEF_DEF_ "BusType" "CAN FD";
BA_ "BusType" "CAN FD";
"""


def dbc_text() -> str:
    return build_database().as_dbc_string()


if __name__ == "__main__":  # pragma: no cover
    DBC_PATH.write_text(dbc_text())
    print(f"wrote {DBC_PATH}")
