"""Prediction for a user's mesh: ``Predictor`` and ``load_predictor`` (``predictor``, the shipped ``fast``
model by default), rigid bodies from mesh files (``body``), the simulator beside the model (``simulator``), and the
prediction files, JSON, .npz or .csv (``prediction_files``)."""
