"""Tests of the DGCNN plugin: the encoder's maths, and that physdyn finds it once the package is installed.

The maths tests run from a source checkout too (the package's src/ is put on sys.path if it is not
installed); the discovery tests need `pip install ./plugins/physdyn-dgcnn` and skip without it.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from physdyn.errors import ConfigError
from physdyn.registry import ENCODERS

PLUGIN_ROOT = Path(__file__).resolve().parents[1]
DIST_NAME = "physdyn-dgcnn"

# Discovery first, as physdyn itself would run it: an installed plugin is then recorded as
# "plugin physdyn-dgcnn". Importing the package before discovery would still register it, as "built-in".
try:
    ENCODERS.names()
except ImportError:  # physdyn's built-in encoders are not there yet: the maths tests still run
    pass

try:
    import physdyn_dgcnn  # noqa: F401
except ModuleNotFoundError:
    sys.path.insert(0, str(PLUGIN_ROOT / "src"))

from physdyn_dgcnn import DGCNNEncoder, EdgeConv, knn_indices  # noqa: E402
from physdyn_dgcnn.encoder import gather_neighbours  # noqa: E402


def small_config(**overrides) -> DGCNNEncoder.Config:
    values = dict(k=8, edge_widths=[16, 16, 32], embedding_width=32, head_widths=[32], feature_dim=16)
    values.update(overrides)
    return DGCNNEncoder.Config(**values)


def cloud(batch: int = 2, n: int = 64, seed: int = 0) -> torch.Tensor:
    """(batch, n, 3) random points in a box about the origin, like a body-frame cloud."""
    g = torch.Generator().manual_seed(seed)
    return torch.rand(batch, n, 3, generator=g) - 0.5


def run_python(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    # Run outside the repository so that what is found is what is installed, not a source tree.
    return subprocess.run(
        [sys.executable, *args], cwd=cwd, capture_output=True, text=True, timeout=300, env=dict(os.environ)
    )


def installed(cwd: Path) -> bool:
    """Whether a fresh interpreter (outside the source tree) sees the distribution.

    Asked of a subprocess: this one may have put src/ on sys.path, where a build's egg-info would look
    like an installed distribution.
    """
    code = f"import importlib.metadata as m; m.distribution({DIST_NAME!r})"
    return run_python(["-c", code], cwd).returncode == 0


@pytest.fixture
def needs_install(tmp_path) -> None:
    # Checked when the test runs, not at collection: tests/test_plugin_install.py may install it meanwhile.
    if not installed(tmp_path):
        pytest.skip(f"{DIST_NAME} is not installed: pip install --no-deps {PLUGIN_ROOT}")


# --------------------------------------------------------------------------------------------------
# The encoder
# --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("mean_pool", [True, False])
@pytest.mark.parametrize("batch_norm", [True, False])
def test_output_shape(mean_pool, batch_norm):
    torch.manual_seed(0)
    encoder = DGCNNEncoder(small_config(mean_pool=mean_pool, batch_norm=batch_norm, feature_dim=7))
    out = encoder(cloud(batch=3, n=50))
    assert encoder.out_dim == 7
    assert out.shape == (3, 7)
    assert out.dtype == torch.float32
    assert torch.isfinite(out).all()


def test_default_config_gives_the_papers_feature_size():
    encoder = DGCNNEncoder()
    assert encoder.out_dim == 16
    assert encoder.config.k == 20
    assert encoder.eval()(cloud(batch=1, n=40)).shape == (1, 16)


def test_cloud_smaller_than_k_and_batch_of_one_in_training():
    torch.manual_seed(0)
    encoder = DGCNNEncoder(small_config(k=20)).train()
    assert encoder(cloud(batch=1, n=5)).shape == (1, 16)


@pytest.mark.parametrize("training", [False, True])
def test_pooled_feature_is_invariant_to_point_order(training):
    torch.manual_seed(0)
    encoder = DGCNNEncoder(small_config()).train(training)
    points = cloud(batch=2, n=64)
    perm = torch.randperm(64)
    with torch.no_grad():
        out = encoder(points)
        out_permuted = encoder(points[:, perm])
    torch.testing.assert_close(out_permuted, out, atol=1e-5, rtol=1e-4)


def test_per_point_features_follow_the_points():
    torch.manual_seed(0)
    encoder = DGCNNEncoder(small_config()).eval()
    points = cloud(n=48)
    perm = torch.randperm(48)
    with torch.no_grad():
        torch.testing.assert_close(
            encoder.point_features(points[:, perm]), encoder.point_features(points)[:, perm], atol=1e-5, rtol=1e-4
        )


def test_translation_changes_the_feature_but_not_the_first_graph():
    # The first EdgeConv sees x_i as well as x_j - x_i, so the feature knows where the centre of mass sits
    # in the cloud (the body frame is centred there): a translated cloud is a different input.
    torch.manual_seed(0)
    encoder = DGCNNEncoder(small_config()).eval()
    points = cloud(n=64)
    shift = torch.tensor([0.3, -0.2, 0.1])
    with torch.no_grad():
        out, out_shifted = encoder(points), encoder(points + shift)
    assert not torch.allclose(out, out_shifted, atol=1e-4)
    # The k-NN graph on xyz depends on differences only.
    assert torch.equal(knn_indices(points, 8), knn_indices(points + shift, 8))


def test_translation_invariant_when_the_first_layer_ignores_x_i():
    # Everything after the first layer is a function of its output, so zeroing the weights on x_i leaves
    # only x_j - x_i: the whole encoder becomes translation invariant. This pins down where the position
    # information enters.
    torch.manual_seed(0)
    encoder = DGCNNEncoder(small_config()).eval()
    with torch.no_grad():
        encoder.edge_convs[0].linear.weight[:, :3] = 0.0
        points = cloud(n=64)
        out = encoder(points)
        out_shifted = encoder(points + torch.tensor([2.0, -1.0, 0.5]))
    torch.testing.assert_close(out_shifted, out, atol=1e-5, rtol=1e-4)


def test_gradient_reaches_every_parameter():
    torch.manual_seed(0)
    encoder = DGCNNEncoder(small_config()).train()
    points = cloud(batch=4, n=48).requires_grad_(True)
    target = torch.randn(4, 16)
    loss = ((encoder(points) - target) ** 2).mean()
    loss.backward()
    for name, p in encoder.named_parameters():
        assert p.grad is not None, f"{name} got no gradient"
        assert torch.isfinite(p.grad).all(), name
        assert p.grad.abs().sum() > 0, f"{name} got a zero gradient"
    assert points.grad is not None and points.grad.abs().sum() > 0


# --------------------------------------------------------------------------------------------------
# The building blocks, against direct formulations
# --------------------------------------------------------------------------------------------------
def test_knn_in_blocks_matches_the_full_distance_matrix():
    points = cloud(batch=2, n=100, seed=1)
    full = torch.cdist(points, points).topk(6, dim=-1, largest=False).indices
    for chunk in (1, 7, 33, 100, 1000):
        assert torch.equal(knn_indices(points, 6, chunk_size=chunk), full)
    # Each point is its own nearest neighbour (distance 0), as in the reference implementation.
    assert torch.equal(full[..., 0], torch.arange(100).expand(2, 100))


def test_knn_rejects_k_larger_than_the_cloud():
    with pytest.raises(ValueError, match="k must be between 1 and the number of points"):
        knn_indices(cloud(n=5), 6)


def test_gather_neighbours():
    values = torch.arange(2 * 4 * 3, dtype=torch.float32).reshape(2, 4, 3)
    idx = torch.tensor([[[1, 2]] * 4, [[3, 0]] * 4])
    out = gather_neighbours(values, idx)
    assert out.shape == (2, 4, 2, 3)
    torch.testing.assert_close(out[1, 0, 0], values[1, 3])
    torch.testing.assert_close(out[0, 2, 1], values[0, 2])


@pytest.mark.parametrize("training", [False, True])
def test_edgeconv_equals_the_reference_formulation(training):
    # Reference (Wang et al.'s code): build [x_i, x_j - x_i], apply the shared layer, BN over all edges,
    # LeakyReLU, max over neighbours. Ours never builds the edge tensor; the result must be the same.
    torch.manual_seed(0)
    conv = EdgeConv(5, 12, batch_norm=True).train(training)
    with torch.no_grad():
        conv.norm.running_mean.uniform_(-0.5, 0.5)
        conv.norm.running_var.uniform_(0.5, 2.0)
        conv.norm.weight.uniform_(-1.5, 1.5)  # negative scales too
        conv.norm.bias.uniform_(-0.5, 0.5)
    x = torch.randn(2, 30, 5)
    idx = knn_indices(x, 6)
    ref_norm = torch.nn.BatchNorm2d(12).train(training)
    ref_norm.load_state_dict(conv.norm.state_dict())

    edges = conv.edge_features(x, idx)  # (B, N, k, 2C)
    h = torch.nn.functional.linear(edges, conv.linear.weight, conv.linear.bias).permute(0, 3, 1, 2)
    expected = torch.nn.functional.leaky_relu(ref_norm(h), 0.2).max(dim=-1).values.transpose(1, 2)

    torch.testing.assert_close(conv(x, idx), expected, atol=1e-5, rtol=1e-4)


# --------------------------------------------------------------------------------------------------
# Config and registry
# --------------------------------------------------------------------------------------------------
def test_bad_config_values_are_config_errors():
    with pytest.raises(ConfigError, match="k must be >= 1"):
        DGCNNEncoder(small_config(k=0))
    with pytest.raises(ConfigError, match="edge_widths"):
        DGCNNEncoder(small_config(edge_widths=[]))
    with pytest.raises(ConfigError, match="feature_dim"):
        DGCNNEncoder(small_config(feature_dim=0))


def test_wrong_input_shape_names_the_shape():
    with pytest.raises(ValueError, match=r"\(B, N, 3\), got \(10, 3\)"):
        DGCNNEncoder(small_config())(torch.zeros(10, 3))


def test_built_through_the_registry_with_a_typed_config():
    try:
        encoder = ENCODERS.build("dgcnn", {"k": 4, "edge_widths": [8, 8], "embedding_width": 16})
    except ImportError as exc:  # physdyn's built-in encoders package is missing or broken
        pytest.skip(f"ENCODERS cannot load its built-ins: {exc}")
    assert isinstance(encoder, DGCNNEncoder)
    assert encoder.config.k == 4 and list(encoder.config.edge_widths) == [8, 8]
    assert encoder(cloud(n=20)).shape == (2, 16)
    with pytest.raises(ConfigError, match=r"'model\.encoder\.params\.kk'"):
        ENCODERS.build("dgcnn", {"kk": 4}, where="model.encoder.params")
    with pytest.raises(ConfigError, match=r"'model\.encoder\.params\.k'.*'many'"):
        ENCODERS.build("dgcnn", {"k": "many"}, where="model.encoder.params")
    with pytest.raises(ConfigError, match=r"'model\.encoder\.params\.edge_widths\[0\]'"):
        ENCODERS.build("dgcnn", {"edge_widths": ["wide"]}, where="model.encoder.params")


# --------------------------------------------------------------------------------------------------
# Discovery, in a fresh interpreter (this one may have imported the package before it was installed)
# --------------------------------------------------------------------------------------------------
def skip_if_builtins_missing(proc: subprocess.CompletedProcess) -> None:
    if proc.returncode != 0 and "No module named 'physdyn." in proc.stderr:
        missing = proc.stderr.strip().splitlines()[-1]
        pytest.skip(f"a physdyn built-in package is not written yet ({missing})")


def test_installed_plugin_is_listed_by_the_encoder_registry(needs_install, tmp_path):
    code = (
        "from physdyn.registry import ENCODERS\n"
        "print(ENCODERS.names())\n"
        "e = {e.name: e for e in ENCODERS.entries()}['dgcnn']\n"
        "print(e.cls.__module__, '|', e.source)\n"
    )
    proc = run_python(["-c", code], tmp_path)
    skip_if_builtins_missing(proc)
    assert proc.returncode == 0, proc.stderr
    names_line, entry_line = proc.stdout.strip().splitlines()[-2:]
    assert "'dgcnn'" in names_line
    assert entry_line == f"physdyn_dgcnn.encoder | plugin {DIST_NAME}"


def test_physdyn_components_lists_dgcnn_as_a_plugin(needs_install, tmp_path):
    proc = run_python(["-m", "physdyn.cli", "components"], tmp_path)
    lines = [line.split() for line in proc.stdout.splitlines()]
    dgcnn = [line for line in lines if line[:1] == ["dgcnn"]]
    if not dgcnn:
        skip_if_builtins_missing(proc)
    assert dgcnn, f"dgcnn not listed:\n{proc.stdout}\n{proc.stderr}"
    assert dgcnn[0][1:3] == ["plugin", DIST_NAME], proc.stdout
    skip_if_builtins_missing(proc)  # dgcnn is listed; only a later built-in kind failed
    assert proc.returncode == 0, proc.stderr
