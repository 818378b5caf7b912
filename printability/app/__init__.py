"""The applications: the command line (:mod:`.cli`), the post-processing server
(:mod:`.server`, its client and connections), the demo (:mod:`.demo`) and the warm-up
(:mod:`.warmup`).

They are the only code that imports ``machine_io`` and ``simulators`` (an import contract in
pyproject.toml).
"""
