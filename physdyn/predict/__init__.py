"""Prediction for a user's mesh: ``Predictor`` and ``load_predictor`` (the bundled model by default),
rigid bodies from mesh files, the simulator beside the model, and the prediction files (JSON, .npz, .csv)."""
