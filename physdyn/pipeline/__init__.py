"""A predictor as a pipeline of registered stages: motion, topple, end correction (``stages``), their
built-ins (``motion``, ``topple``, ``correction``), the presets and the factory that builds any of them
(``presets``), and the roll-out engine that runs them in order (``engine``); a trajectory's integration
(``trajectory``). docs/architecture.md, "Stages and presets"."""
