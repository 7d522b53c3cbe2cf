"""The test suite, one folder per package: tests/hal, tests/emulators, tests/servo, tests/vmehil.

A package (with this file) so that pytest imports every test module by its full dotted name
(``tests.hal.test_adc``) with the repository root on ``sys.path``: the helpers in
:mod:`tests.support` import as ``tests.support.…`` and test modules may share basenames.
"""
