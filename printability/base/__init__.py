"""The leaf layer of the project: basics every other layer may use.

:mod:`~printability.base.errors` (the exception hierarchy), :mod:`~printability.base.options`
(the string-option registries), :mod:`~printability.base.settings` (the frozen tolerances),
:mod:`~printability.base.arrays` (array helpers of the hot paths),
:mod:`~printability.base.files` (atomic writes), :mod:`~printability.base.parallel` (a
compiled kernel's items shared out over threads) and :mod:`~printability.base.kernel_cache`.

These modules import only the standard library, numpy and each other — never another part
of ``printability`` nor ``gcode``, ``machine_io``, ``simulators`` or ``plugin`` (an
import-linter contract in ``pyproject.toml``, checked by ``tests/test_layers.py``). Importing
them runs nothing else: ``printability/__init__`` is light; :mod:`~printability.base.kernel_cache`
(the on-disk kernel caches kept in step with their sources) checks the caches only before the
first kernel compiles or loads.
"""
