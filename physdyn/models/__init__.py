"""Models: shape encoders, state predictors, heads, losses and the LightningModule."""
