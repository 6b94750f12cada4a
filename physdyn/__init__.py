"""physdyn: learn to predict the physical dynamics of unseen 3D objects (Rempe et al., WACV 2020)."""

__version__ = "0.3.0"


def __getattr__(name: str):
    # Lazy: `import physdyn` stays light; torch and the model load only when a predictor is asked for.
    if name == "load_predictor":
        from physdyn.predict.predictor import load_predictor

        return load_predictor
    if name == "plan_push":
        from physdyn.plan import plan_push

        return plan_push
    raise AttributeError(f"module 'physdyn' has no attribute {name!r}")
