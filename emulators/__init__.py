"""Register-level board emulators, the emulated VME crate, and the joint plant.

``emulators`` imports ``hal`` for register maps only (one source of truth per board).
"""
