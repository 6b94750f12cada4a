"""`physdyn pretrain`: train a shape encoder on shape classification, for `physdyn fit` to start from.

The paper initialised its PointNet from ModelNet40 classification weights. By default the classes here
are the procedural shape families (``SHAPE_FAMILIES``: primitives, bottles, mugs, ...); with
``data.modelnet_root`` a ModelNet40-layout folder (``<root>/<class>/{train,test}/*.off``) is used instead.
Clouds are centred on their centroid and divided by the largest point norm of the training clouds, as
`physdyn fit` divides its body-frame clouds by the training maximum. The result, ``<out_dir>/encoder.pt``,
holds ``{"encoder": name, "params": {...}, "state_dict": {...}, "classes": [...]}``; pass it as
``model.encoder_init``.
"""

from __future__ import annotations

import contextlib
import json
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import lightning
import numpy as np
import torch
import trimesh
from lightning import LightningModule
from lightning.pytorch.callbacks import ModelCheckpoint
from torch import nn
from torch.utils.data import DataLoader, TensorDataset

from physdyn.config import OptimConfig, PretrainConfig, PretrainDataConfig, load_config, to_dict
from physdyn.errors import ConfigError, ShapeError
from physdyn.geometry.sampling import sample_surface_points
from physdyn.models.checkpoint_file import read_torch_file, write_torch_file
from physdyn.models.optimizer import adam_with_schedule
from physdyn.files import write_text_atomic
from physdyn.models.run_directory import (
    FINISHED, is_global_zero_process, prepare_run_directory, run_directory, save_config_yaml,
)
from physdyn.models.trainer_setup import build_trainer, ignore_lightning_noise, validate_trainer_args
from physdyn.registry import ENCODERS, SHAPE_FAMILIES
from physdyn.write_lock import write_lock

DEFAULT_SHAPES_PER_FAMILY = 40


@dataclass
class ShapeClouds:
    """train_points/val_points: (K, N, 3) float32 centred clouds; *_labels: (K,) int64; classes: names."""

    train_points: np.ndarray
    train_labels: np.ndarray
    val_points: np.ndarray
    val_labels: np.ndarray
    classes: list[str]


@dataclass
class PretrainResult:
    encoder_path: Path
    out_dir: Path
    metrics: dict[str, float] = field(default_factory=dict)


def _sample(mesh, cfg: PretrainDataConfig, seed: int) -> np.ndarray:
    try:
        pts = sample_surface_points(mesh, cfg.num_points, cfg.oversample, seed)
    except ImportError:  # open3d missing: plain area-weighted sampling
        pts = mesh.sample(cfg.num_points, seed=seed)
    pts = np.asarray(pts, dtype=np.float32)
    return pts - pts.mean(axis=0, keepdims=True)


def load_modelnet(cfg: PretrainDataConfig, seed: int) -> ShapeClouds:
    root = Path(cfg.modelnet_root).expanduser()
    classes = sorted(p.name for p in root.iterdir() if p.is_dir()) if root.is_dir() else []
    if not classes:
        raise ConfigError(f"config key 'data.modelnet_root': {root} has no class folders (<root>/<class>/train/*.off)")
    out: dict[str, tuple[list, list]] = {"train": ([], []), "test": ([], [])}
    for label, name in enumerate(classes):
        for split, (points, labels) in out.items():
            files = sorted((root / name / split).glob("*.off"))[: cfg.max_per_class]
            for i, path in enumerate(files):
                try:
                    mesh = trimesh.load(path, force="mesh")
                except Exception as exc:
                    warnings.warn(f"skipping {path}: {type(exc).__name__}: {exc}", stacklevel=2)
                    continue
                if len(mesh.faces) == 0:
                    continue
                mesh.apply_scale(cfg.modelnet_scale)
                points.append(_sample(mesh, cfg, seed + i))
                labels.append(label)
    if not out["train"][0]:
        raise ConfigError(f"config key 'data.modelnet_root': no readable .off files under {root}/<class>/train/")
    if not out["test"][0]:
        raise ConfigError(f"config key 'data.modelnet_root': no readable .off files under {root}/<class>/test/")
    arr = lambda x: (np.stack(x[0]).astype(np.float32), np.asarray(x[1], np.int64))  # noqa: E731
    return ShapeClouds(*arr(out["train"]), *arr(out["test"]), classes)


def load_families(cfg: PretrainDataConfig, seed: int) -> ShapeClouds:
    counts = dict(cfg.families) or {n: DEFAULT_SHAPES_PER_FAMILY for n in SHAPE_FAMILIES.names() if n != "meshes"}
    if not counts:
        raise ConfigError("config key 'data.families': no shape families registered; pass data.modelnet_root=...")
    classes = sorted(counts)
    points, labels = [], []
    for label, name in enumerate(classes):
        family = SHAPE_FAMILIES.build(name, None, f"data.families.{name}")
        made = 0
        for index in range(family.num_shapes(int(counts[name]))):
            rng = np.random.default_rng([seed, label, index])
            try:
                shape = family.make(index, rng)
            except ShapeError:
                continue
            points.append(_sample(shape.mesh, cfg, seed + index))
            labels.append(label)
            made += 1
        if made == 0:
            raise ConfigError(f"config key 'data.families.{name}': the family produced no usable shape")
    points_arr, labels_arr = np.stack(points).astype(np.float32), np.asarray(labels, np.int64)
    order = np.random.default_rng(seed).permutation(len(labels_arr))
    n_val = int(round(cfg.val_fraction * len(order)))
    val, train = order[:n_val], order[n_val:]
    if len(train) == 0:
        raise ConfigError("config key 'data.val_fraction': leaves no training shapes")
    if len(val) == 0:
        val = train  # too few shapes for a held-out set: report the training fit
    return ShapeClouds(points_arr[train], labels_arr[train], points_arr[val], labels_arr[val], classes)


def load_shape_clouds(cfg: PretrainDataConfig, seed: int) -> ShapeClouds:
    return load_modelnet(cfg, seed) if cfg.modelnet_root else load_families(cfg, seed)


def augment(points: torch.Tensor) -> torch.Tensor:
    """Random rotation about z (objects rest in any heading), scale 0.8-1.25 and 1 % jitter. points: (B, N, 3)."""
    B = points.shape[0]
    angle = torch.rand(B, device=points.device) * 2 * torch.pi
    c, s = torch.cos(angle), torch.sin(angle)
    R = torch.zeros(B, 3, 3, device=points.device)
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, 1.0
    scale = torch.exp(torch.empty(B, 1, 1, device=points.device).uniform_(np.log(0.8), np.log(1.25)))
    return torch.einsum("bij,bnj->bni", R, points) * scale + 0.01 * torch.randn_like(points)


class ShapeClassifier(LightningModule):
    """A registered shape encoder + one linear layer to class logits."""

    def __init__(self, encoder: dict, num_classes: int, point_scale: float, optim: dict, augment: bool = True,
                 batch_size: int = 1):
        super().__init__()
        self.save_hyperparameters()
        self.encoder = ENCODERS.build(encoder["name"], encoder.get("params", {}), "encoder.params")
        self.classifier = nn.Linear(self.encoder.out_dim, num_classes)
        self.point_scale = float(point_scale)
        self.augment = augment

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        return self.classifier(self.encoder(points / self.point_scale))

    def _step(self, batch, prefix: str, train: bool) -> torch.Tensor:
        points, labels = batch
        if train and self.augment:
            points = augment(points)
        logits = self(points)
        loss = nn.functional.cross_entropy(logits, labels)
        acc = (logits.argmax(dim=1) == labels).float().mean()
        self.log(f"{prefix}/loss", loss, prog_bar=True, on_step=train, on_epoch=True, batch_size=len(labels), sync_dist=not train)
        self.log(f"{prefix}/acc", acc, prog_bar=True, on_step=False, on_epoch=True, batch_size=len(labels), sync_dist=not train)
        return loss

    def training_step(self, batch, batch_idx):
        return self._step(batch, "train", True)

    def validation_step(self, batch, batch_idx):
        self._step(batch, "val", False)

    def configure_optimizers(self):
        total = float(self.trainer.estimated_stepping_batches)
        per_step = self.hparams.get("batch_size", 1) * self.trainer.world_size
        return adam_with_schedule(self.parameters(), OptimConfig(**self.hparams.optim), total, per_step)


def load_pretrain_config(path, overrides: list[str] | None = None) -> PretrainConfig:
    cfg = load_config(PretrainConfig, path, overrides)
    if not cfg.encoder.name:
        raise ConfigError(f"config key 'encoder.name': missing; registered: {', '.join(ENCODERS.names())}")
    ENCODERS.resolve_config(cfg.encoder.name, cfg.encoder.params, "encoder.params", name_key="encoder.name")
    for name in cfg.data.families:
        if name not in SHAPE_FAMILIES.names():
            raise ConfigError(f"config key 'data.families.{name}': unknown shape family; registered: {', '.join(SHAPE_FAMILIES.names())}")
    if not 0 <= cfg.data.val_fraction < 1:
        raise ConfigError(f"config key 'data.val_fraction': must be in [0, 1), got {cfg.data.val_fraction}")
    validate_trainer_args(cfg.trainer)
    return cfg


def save_encoder(encoder: nn.Module, name: str, params: dict, classes: list[str], path: Path) -> None:
    state = {k: v.detach().cpu() for k, v in encoder.state_dict().items()}
    # a crash keeps the previous encoder.pt, never half of one
    write_torch_file({"encoder": name, "params": params, "state_dict": state, "classes": classes}, path)


def pretrain(config: PretrainConfig, overwrite: bool = False) -> PretrainResult:
    """Train ``config.encoder`` to classify shapes; write ``<out_dir>/encoder.pt`` (see module docstring)."""

    cfg = config
    out_dir = run_directory(cfg)
    with write_lock(out_dir) if is_global_zero_process() else contextlib.nullcontext():  # one run per folder
        return _pretrain(cfg, out_dir, overwrite)


def _pretrain(cfg: PretrainConfig, out_dir: Path, overwrite: bool) -> PretrainResult:
    prepare_run_directory(out_dir, resume=False, overwrite=overwrite, what="physdyn pretrain", resumable=False)
    lightning.seed_everything(cfg.seed, workers=True, verbose=False)
    clouds = load_shape_clouds(cfg.data, cfg.seed)
    point_scale = float(np.linalg.norm(clouds.train_points, axis=-1).max()) or 1.0
    encoder_cfg = to_dict(cfg.encoder)
    model = ShapeClassifier(encoder_cfg, len(clouds.classes), point_scale, to_dict(cfg.optim), cfg.data.augment,
                            batch_size=cfg.data.batch_size)
    save_config_yaml(cfg, out_dir / "config.yaml")
    ds = lambda p, l: TensorDataset(torch.from_numpy(p), torch.from_numpy(l))  # noqa: E731
    bs = cfg.data.batch_size
    n_train = len(clouds.train_labels)
    train_loader = DataLoader(ds(clouds.train_points, clouds.train_labels), batch_size=bs, shuffle=True,
                              drop_last=n_train >= bs and n_train % bs == 1, num_workers=cfg.data.num_workers)
    val_loader = DataLoader(ds(clouds.val_points, clouds.val_labels), batch_size=bs, num_workers=cfg.data.num_workers)
    checkpoint = ModelCheckpoint(dirpath=out_dir, filename="best", monitor="val/loss", mode="min", save_top_k=1,
                                 save_last=True, auto_insert_metric_name=False, enable_version_counter=False)
    trainer = build_trainer(cfg.trainer, out_dir, [checkpoint], cfg.progress_bar)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*smaller than the logging interval.*")
        warnings.filterwarnings("ignore", message=".*does not have many workers.*")
        warnings.filterwarnings("ignore", message=".*exists and is not empty.*")  # our config.yaml is there
        ignore_lightning_noise()
        trainer.fit(model, train_loader, val_loader)
    if checkpoint.best_model_path:
        best = read_torch_file(checkpoint.best_model_path, "the best.ckpt this run wrote")
        model.load_state_dict(best["state_dict"])
    metrics = {k: float(v) for k, v in trainer.callback_metrics.items() if torch.is_tensor(v) and v.numel() == 1}
    encoder_path = out_dir / "encoder.pt"
    if trainer.is_global_zero:
        save_encoder(model.encoder, cfg.encoder.name, dict(cfg.encoder.params), clouds.classes, encoder_path)
        write_text_atomic(out_dir / FINISHED, json.dumps({"metrics": metrics, "classes": clouds.classes}, indent=2))
    return PretrainResult(encoder_path, out_dir, metrics)
