"""User-facing errors: raised where bad input enters, printed by the CLI as one line."""


class PhysdynError(Exception):
    """An error the user can fix. The message names the problem and the fix, on one line."""


class ConfigError(PhysdynError):
    """A malformed config file or override."""


class ShapeError(PhysdynError):
    """A mesh that cannot be used: empty, degenerate, unreadable, NaN vertices..."""


class StoreError(PhysdynError):
    """A dataset store that is missing, incomplete, corrupt or would be overwritten."""


class PredictionError(PhysdynError):
    """Bad input to a prediction: a vector, a duration, an output path."""


class PredictionWarning(UserWarning):
    """Something the user should know about a prediction that still runs (e.g. an open mesh)."""


class CheckpointError(PhysdynError):
    """A checkpoint path that is missing or does not hold a physdyn DynamicsModel."""
