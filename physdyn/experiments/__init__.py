"""The paper's experiments as one resumable suite and the results page built from it (``reproduce``)."""
