"""vmehil hardware abstraction layer: drivers that talk only to a :class:`hal.vme.VmeBus`.

``hal`` never imports ``emulators`` or ``servo``; each board's register map is declared once
here and shared with its emulator.
"""
