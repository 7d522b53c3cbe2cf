#!/usr/bin/env bash
# vcan_setup.sh — create and bring up a virtual CAN (FD-capable) interface for vmehil.
#
#   sudo ./vcan_setup.sh            # loads vcan, creates vcan0 with MTU 72 (CAN FD), brings it up
#   sudo ./vcan_setup.sh vcan1      # same for another name
#   sudo ./vcan_setup.sh --down     # removes vcan0 (or: --down vcan1)
#
# Idempotent: running it twice leaves one interface up. Needs root, iproute2 (`ip`) and a
# kernel with the vcan module (SocketCAN). Exits non-zero with a message naming what is missing.
set -euo pipefail

usage() {
    echo "usage: $0 [--down] [IFNAME]   (default IFNAME: vcan0)" >&2
    exit 2
}

down=0
ifname=vcan0
for arg in "$@"; do
    case "$arg" in
        --down) down=1 ;;
        -h|--help) usage ;;
        -*) echo "$0: unknown option $arg" >&2; usage ;;
        *) ifname=$arg ;;
    esac
done

if [ "$(id -u)" -ne 0 ]; then
    echo "$0: must run as root (try: sudo $0 $*)" >&2
    exit 1
fi
if ! command -v ip >/dev/null 2>&1; then
    echo "$0: 'ip' not found; install iproute2 (Debian: apt-get install iproute2)" >&2
    exit 1
fi

if [ "$down" -eq 1 ]; then
    if ip link show "$ifname" >/dev/null 2>&1; then
        ip link delete "$ifname"
        echo "$ifname removed"
    else
        echo "$ifname does not exist; nothing to do"
    fi
    exit 0
fi

if ! ip link show "$ifname" >/dev/null 2>&1; then
    if ! modprobe vcan 2>/dev/null && ! [ -d /sys/module/vcan ]; then
        echo "$0: cannot load the vcan kernel module; this kernel has no SocketCAN vcan support" >&2
        echo "    (use python-can's 'virtual' or 'udp_multicast' interface instead, see docs/can.md)" >&2
        exit 1
    fi
    ip link add dev "$ifname" type vcan
fi
# MTU 72 = CANFD_MTU: the interface then carries CAN FD frames as well as classic ones.
ip link set "$ifname" mtu 72
ip link set up "$ifname"
echo "$ifname is up (CAN FD, MTU 72)"
