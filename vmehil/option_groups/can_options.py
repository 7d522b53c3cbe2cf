"""CAN options for the command line: ``vmehil run --plant can …`` (a ``RUN_EXTENSIONS`` module of
:mod:`vmehil.commands.run`), the simulating ``vmehil tune`` subcommands (``limit-cycle``, ``step``,
``sweep``) and the shared option set of ``vmehil plant-node``.

    --plant inprocess|can        where the plant runs (default inprocess)
    --interface NAME             python-can interface: virtual | socketcan | udp_multicast
                                 (default: CAN_INTERFACE / python-can config / virtual)
    --channel NAME               python-can channel (default: CAN_CHANNEL / config / per interface)
    --plant-mode lockstep|free-running   must match the node (default lockstep)
    --can-log PATH               record the bus (.log = candump format; .asc/.blf/.csv also work)
    --can-timeout S              lockstep answer timeout and heartbeat timeout (default 1.0 s)
    --stale-ticks N              exchanges without fresh data before the safe stop

Shared pieces: :func:`add_arguments` (the option group), :class:`CanPlantOptions` (the options as
a picklable value), :func:`make_link` (``vmehil run``: one link to an external node) and
:func:`link_factory` (``vmehil tune``: a :class:`CanLinkFactory` that opens a fresh link per
simulated run and, on the ``virtual`` interface, a fresh in-process plant node thread on a
channel of its own).
"""

from __future__ import annotations

import argparse
import functools
import itertools
import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Protocol

from vmehil.errors import CliError
from vmehil.option_groups.cli_types import bounded_float, bounded_int

PLANT_MODES = ("lockstep", "free-running")
_node_channels = itertools.count()


def add_bus_arguments(p: argparse.ArgumentParser) -> None:
    """``--interface``, ``--channel``, ``--can-log`` (python-can conventions)."""
    p.add_argument("--interface", default=None, metavar="NAME",
                   help="python-can interface: virtual (this process only: `run` starts the plant node itself), "
                        "socketcan or udp_multicast (between processes) (default: CAN_INTERFACE, python-can's "
                        "config file, else virtual)")
    p.add_argument("--channel", default=None, metavar="NAME",
                   help="python-can channel (default: CAN_CHANNEL, config file, else vmehil / vcan0 / 239.74.163.2)")
    p.add_argument("--can-log", default=None, metavar="PATH",
                   help="record the bus from this side (.log = candump format, decodable with cantools decode)")


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The plant-over-CAN option group (``vmehil run`` and the simulating ``vmehil tune`` commands)."""
    g = p.add_argument_group("plant node over CAN")
    g.add_argument("--plant", choices=("inprocess", "can"), default="inprocess",
                   help="run the plant in this process (default) or talk to `vmehil plant-node` over CAN")
    add_bus_arguments(g)  # type: ignore[arg-type]
    g.add_argument("--plant-mode", choices=PLANT_MODES, default="lockstep",
                   help="lockstep (tick per exchange; equals the in-process run) or free-running (latch newest)")
    g.add_argument("--can-timeout", type=bounded_float(0.001, 3600.0, what="a timeout (s)"), default=1.0, metavar="S",
                   help="answer / heartbeat timeout in seconds (1.0)")
    g.add_argument("--stale-ticks", type=bounded_int(1, 100_000, what="a number of ticks"), default=None, metavar="N",
                   help="exchanges without fresh plant data before a safe stop (lockstep 1, free-running 5)")


add_plant_arguments = add_arguments


@dataclass(frozen=True)
class CanPlantOptions:
    """The ``--plant can`` options as a value (picklable: sweep workers receive it).

    ``own_node``: start an in-process :class:`~emulators.can.node.PlantNode` thread per link, on
    a channel of its own (``<channel>-<pid>-<n>``); None = when the resolved interface is
    ``virtual`` (python-can's ``virtual`` bus only reaches this process, so no other node can
    answer there from the command line).
    """

    interface: str | None = None
    channel: str | None = None
    plant_mode: str = "lockstep"
    can_log: str | None = None
    can_timeout_s: float = 1.0
    stale_ticks: int | None = None
    own_node: bool | None = None

    def __post_init__(self) -> None:
        if self.plant_mode not in PLANT_MODES:
            raise CliError(f"plant mode {self.plant_mode!r} must be one of {', '.join(PLANT_MODES)}")
        if not self.can_timeout_s > 0:
            raise CliError(f"--can-timeout {self.can_timeout_s} must be > 0 s")
        if self.stale_ticks is not None and self.stale_ticks < 1:
            raise CliError(f"--stale-ticks {self.stale_ticks} must be at least 1")

    @classmethod
    def from_args(cls, args: argparse.Namespace, *, own_node: bool | None = None) -> CanPlantOptions | None:
        """The options of ``--plant can``; None for ``--plant inprocess`` (or no such options)."""
        if args.plant != "can":
            return None
        return cls(args.interface, args.channel, args.plant_mode, args.can_log, args.can_timeout,
                   args.stale_ticks, own_node)

    def resolved(self) -> tuple[str, str]:
        """Interface and channel after python-can's configuration rules."""
        from emulators.can.bus import resolve

        return resolve(self.interface, self.channel)

    @property
    def starts_node(self) -> bool:
        """True when each link brings its own in-process plant node."""
        if self.own_node is not None:
            return self.own_node
        return self.resolved()[0] == "virtual"

    def log_path(self, tag: str | None) -> str | None:
        """``--can-log`` for one of several runs: ``bus.log`` → ``bus-<tag>.log``."""
        if not self.can_log or not tag:
            return self.can_log
        p = Path(self.can_log)
        return str(p.with_name(f"{p.stem}-{tag}{p.suffix}"))

    def open_link(self, rig: Any, seed: int, *, tag: str | None = None):
        """A connected :class:`~emulators.can.can_plant_link.CanPlantLink` whose plant was RESET with
        ``seed``. ``rig``: a :class:`servo.rig.RigSpec`, preset name or rig file path. With
        :attr:`starts_node`, the link owns a fresh plant node thread, stopped by its ``close()``.

        Raises ValueError (no node answered, wrong rig or mode) with what to change.
        """
        from emulators.can.bus import Endpoint, open_bus
        from emulators.can.can_plant_link import CONTROLLER_IDS
        from emulators.harness import PlantLinkError

        names, node = self._names(rig), None
        iface, chan = self.resolved()
        if self.starts_node:
            chan = f"{chan}-{os.getpid()}-{next(_node_channels)}"
            node = _start_node(rig, iface, chan, free_running=self.plant_mode == "free-running")
        try:
            ep = Endpoint(open_bus(iface, chan), CONTROLLER_IDS, log_path=self.log_path(tag))
        except BaseException:
            if node is not None:
                node.stop()
            raise
        try:
            link = _owning_link_type()(ep, names, seed=seed, free_running=self.plant_mode == "free-running",
                                       answer_timeout_s=self.can_timeout_s, heartbeat_timeout_s=self.can_timeout_s,
                                       stale_ticks=self.stale_ticks)
        except BaseException:
            ep.close()
            if node is not None:
                node.stop()
            raise
        link.node = node
        try:
            link.connect()
            return link
        except PlantLinkError as e:  # no node / wrong rig or mode: a user error, not a crash
            link.close()
            raise CliError(f"{e}{self._advice(e, rig, iface, chan, node is not None)}") from e
        except BaseException:
            link.close()
            raise

    def _advice(self, e: Exception, rig: Any, iface: str, chan: str, own_node: bool) -> str:
        """What to do when connecting failed — advice that works when followed."""
        from emulators.harness import PlantLostError

        if not isinstance(e, PlantLostError):
            return ""
        if own_node:
            return (f" (the plant node this process started on {iface} {chan} did not answer: a bug; "
                    "run again with --debug and report it)")
        if iface == "virtual":
            return (": python-can's virtual bus reaches this process only; leave --interface out (vmehil run "
                    "--plant can then starts the node in this process) or use udp_multicast/socketcan")
        rig_name = _rig_argument(rig)
        mode = " --free-running" if self.plant_mode == "free-running" else ""
        where = (" in the same network namespace (docs/can.md, 'Running it')" if iface == "udp_multicast"
                 else "")
        return (f": start the node first, in another shell{where}: vmehil plant-node --rig {rig_name} "
                f"--interface {iface} --channel {chan}{mode}")

    @staticmethod
    def _names(rig: Any) -> list[str]:
        joints = getattr(rig, "joints", None)
        if joints is not None:
            return [j.name for j in joints]
        from emulators.can.node import node_spec

        return node_spec(None if rig is None else str(rig)).names


def _rig_argument(rig: Any) -> str:
    """What to give ``--rig`` for ``rig`` (a RigSpec, name or path): a preset's name, else its file."""
    from emulators.presets import resolve_rig

    path, name = getattr(rig, "path", None), getattr(rig, "name", None)
    if path is None:
        return "jpl-arm" if rig is None else str(rig)
    try:
        if name and Path(resolve_rig(name)).resolve() == Path(path).resolve():
            return str(name)
    except FileNotFoundError:
        pass
    return str(path)


class _PlantNodeThread:
    """An in-process plant node serving in a daemon thread."""

    def __init__(self, node: Any) -> None:
        self.node = node
        self.thread, self.event = node.start_thread()

    def stop(self) -> None:
        self.event.set()
        self.thread.join(10)
        self.node.close()


def _start_node(rig: Any, interface: str, channel: str, *, free_running: bool) -> _PlantNodeThread:
    from emulators.can.bus import Endpoint, open_bus
    from emulators.can.node import PLANT_IDS, PlantNode, node_spec
    from emulators.plant import Plant
    from vmehil.rig_setup.system import NON_PLANT_JOINT_KEYS

    spec = node_spec(str(getattr(rig, "path", rig)) if rig is not None else None, foreign_keys=NON_PLANT_JOINT_KEYS)
    node = PlantNode(Endpoint(open_bus(interface, channel), PLANT_IDS),
                     lambda seed: Plant.from_config(spec.table, seed=seed), spec.n_joints,
                     free_running=free_running, period_s=spec.period_s, delay_s=spec.delay_s)
    return _PlantNodeThread(node)


@functools.cache
def _owning_link_type() -> type:
    """:class:`~emulators.can.can_plant_link.CanPlantLink` that also stops the node it brought (if any);
    built on first use so that the CLI does not import python-can unless ``--plant can`` is given."""
    from emulators.can.can_plant_link import CanPlantLink

    class NodeOwningCanPlantLink(CanPlantLink):
        node: _PlantNodeThread | None = None

        def close(self) -> None:
            try:
                super().close()
            finally:
                node, self.node = self.node, None
                if node is not None:
                    node.stop()

    return NodeOwningCanPlantLink


@dataclass(frozen=True)
class CanLinkFactory:
    """``factory(rig, seed) -> PlantLink``: a fresh, connected CAN link per simulated run
    (:func:`vmehil.analysis.simulate.simulate`'s ``link_factory``). Picklable. ``tag`` names the
    run's bus log (``--can-log bus.log`` → ``bus-<tag>.log``)."""

    options: CanPlantOptions
    tag: str | None = None

    def __call__(self, rig: Any, seed: int):
        return self.options.open_link(rig, seed, tag=self.tag)

    def tagged(self, tag: str) -> CanLinkFactory:
        return replace(self, tag=tag)

    @property
    def shareable(self) -> bool:
        """True when parallel runs may each open their own link (each brings its own node)."""
        return self.options.starts_node


class RunNeeds(Protocol):
    """What of ``vmehil run``'s options (:class:`vmehil.commands.run_options.RunOptions`) the plant link reads."""

    @property
    def plant(self) -> CanPlantOptions | None: ...
    @property
    def seed(self) -> int: ...
    @property
    def quiet(self) -> bool: ...


def link_factory(options: CanPlantOptions | None) -> CanLinkFactory | None:
    """The link factory of ``--plant can`` for the tuning commands, else None (in-process plant).
    On ``virtual`` every link starts its own plant node thread; on ``socketcan``/``udp_multicast``
    the links talk to the external ``vmehil plant-node`` (one run at a time)."""
    return None if options is None else CanLinkFactory(options)


def make_link(run: RunNeeds, rig: Any):
    """``vmehil run``: the :class:`~emulators.can.can_plant_link.CanPlantLink` for ``--plant can``, else
    ``None``. On ``virtual`` (the default: python-can's virtual bus reaches this process only) it
    starts the plant node in this process, as ``vmehil tune`` does; on ``socketcan`` and
    ``udp_multicast`` it talks to the ``vmehil plant-node`` already on the bus."""
    opts = run.plant
    if opts is None:
        return None
    link = opts.open_link(rig, run.seed)
    if link.node is not None and not run.quiet:
        import sys

        iface = opts.resolved()[0]
        print(f"plant node: in this process on {iface} (python-can's virtual bus does not cross processes; "
              f"for a node in another process use --interface udp_multicast or socketcan)", file=sys.stderr)
    return link


def attach(run: RunNeeds, system: Any, loop: Any, runner: Any, prepared: None = None) -> None:
    """Nothing to attach: the link is closed with the system."""
    return None
