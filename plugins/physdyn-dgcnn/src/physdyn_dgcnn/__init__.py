"""physdyn-dgcnn: an example physdyn plugin adding a DGCNN shape encoder named ``dgcnn``.

physdyn finds this package through its ``physdyn.encoders`` entry point (see pyproject.toml) and imports
it; the import runs ``@ENCODERS.register("dgcnn")`` in ``encoder.py``. Nothing else is needed.
"""

from physdyn_dgcnn.encoder import DGCNNEncoder, EdgeConv, knn_indices

__all__ = ["DGCNNEncoder", "EdgeConv", "knn_indices"]
__version__ = "0.1.0"
