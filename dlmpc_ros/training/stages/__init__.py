"""The stages of ``dlmpc-train``, one module each: ``vae``, ``kmap``, ``mprnn``,
``baselines`` and ``curve``. Each reads the datasets of ``dlmpc-data`` and the files of
earlier stages from a :class:`~dlmpc_ros.training.workspace.Workspace`, trains or builds,
measures, and writes its file (with config, metrics and data fingerprint) and figures."""
