"""The LightningDataModule: random training windows and fixed validation windows from one store.

The whole store is read into memory once in ``setup`` (``load_store``); DataLoader workers never touch
Zarr, which can deadlock in forked workers. Items are simulation indices; the
collate function draws window starts and point subsets for the whole batch at once and gathers the
arrays with ``WindowSource`` (vectorised), so data loading stays a small share of a training step.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import torch
from lightning import LightningDataModule
from torch.utils.data import DataLoader, Dataset

from physdyn.data import SPLITS
from physdyn.config import TrainDataConfig
from physdyn.data.normalization import Normalization, compute_normalization
from physdyn.data.store import StoreData, load_store
from physdyn.data.windows import WindowSource, subsample_indices, turned_about_vertical
from physdyn.errors import ConfigError



def select_sims(store: StoreData, split: int, categories: list[str] = (), exclude: list[str] = ()) -> np.ndarray:
    """Indices of the simulations of ``split`` whose shape category is kept by ``categories``/``exclude``."""
    names = list(store.category_names)
    for key, wanted in (("data.categories", categories), ("data.exclude_categories", exclude)):
        unknown = [c for c in wanted if c not in names]
        if unknown:
            raise ConfigError(
                f"config key '{key}': unknown category '{unknown[0]}' in {store.url}; "
                f"the store has: {', '.join(names) or 'none'}"
            )
    cat = store.sim_category()
    keep = store.split == split
    if categories:
        keep &= np.isin(cat, [names.index(c) for c in categories])
    if exclude:
        keep &= ~np.isin(cat, [names.index(c) for c in exclude])
    return np.flatnonzero(keep)


MAX_BATCH_BYTES = 4 * 2**30  # one batch's arrays; beyond it a typo (window=100000) would exhaust the memory


class SimIndexDataset(Dataset):
    """Items are (simulation, start) pairs; start -1 means "draw a random start"."""

    def __init__(self, sims: np.ndarray, starts: np.ndarray | None = None):
        self.sims = np.asarray(sims, dtype=np.int64)
        self.starts = np.full(len(self.sims), -1, np.int64) if starts is None else np.asarray(starts, np.int64)

    def __len__(self) -> int:
        return len(self.sims)

    def __getitem__(self, i: int) -> tuple[int, int, int]:
        return int(self.sims[i]), int(self.starts[i]), i


class WindowCollate:
    """Turns a list of (sim, start, item) into a batch of tensors (see ``WindowSource.gather``).

    Random starts and point subsets come from a generator private to each process (DataLoader worker or
    DDP rank), seeded from torch's seed there, so workers never repeat each other's windows. With
    ``fixed_seed`` (validation) every item's points are drawn from a generator seeded by its index: the
    same windows every epoch and every run.
    """

    def __init__(self, source: WindowSource, num_points: int | None, fixed_seed: int | None = None,
                 first_window_fraction: float = 0.0, yaw_augment: bool = False):
        self.source = source
        self.first_window_fraction = first_window_fraction
        self.yaw_augment = yaw_augment
        self.num_points = num_points
        self.fixed_seed = fixed_seed
        self._rng: np.random.Generator | None = None
        self._rng_key: tuple | None = None

    def _process_rng(self) -> np.random.Generator:
        info = torch.utils.data.get_worker_info()
        rank = torch.distributed.get_rank() if torch.distributed.is_available() and torch.distributed.is_initialized() else 0
        key = (info.id if info is not None else -1, rank)
        if self._rng is None or self._rng_key != key:
            self._rng = np.random.default_rng([torch.initial_seed() % 2**63, rank, key[0] + 1])
            self._rng_key = key
        return self._rng

    def __call__(self, items: list[tuple[int, int, int]]) -> dict[str, torch.Tensor]:
        sims = np.array([it[0] for it in items], np.int64)
        starts = np.array([it[1] for it in items], np.int64)
        n_avail = self.source.store.points.shape[1]
        if self.fixed_seed is None:
            rng = self._process_rng()
            drawn = self.source.random_starts(sims, rng)
            if self.first_window_fraction > 0:  # windows that start where every roll-out starts
                drawn = np.where(rng.random(len(sims)) < self.first_window_fraction, 0, drawn)
            starts = np.where(starts < 0, drawn, starts)
            index = subsample_indices(n_avail, self.num_points, rng, len(sims))
        else:
            index = None
            if self.num_points is not None and self.num_points < n_avail:
                index = np.stack(
                    [subsample_indices(n_avail, self.num_points, np.random.default_rng([self.fixed_seed, it[2]]), 1)[0] for it in items]
                )
        batch = self.source.gather(sims, starts, index)
        if self.yaw_augment and self.fixed_seed is None:
            batch = turned_about_vertical(batch, rng.uniform(0.0, 2 * np.pi, len(sims)))
        return {k: torch.from_numpy(np.ascontiguousarray(v)) for k, v in batch.items()}


@dataclass
class SplitInfo:
    train: np.ndarray
    val: np.ndarray
    test: np.ndarray


class DynamicsDataModule(LightningDataModule):
    """Windows of ``config.window`` steps from ``config.store``.

    After ``setup()``: ``store`` (StoreData), ``source`` (WindowSource), ``sims`` (train/val/test
    simulation indices after category selection), ``normalization`` (from the training split only) and
    ``rate_hz``. One training epoch = one random window from every training simulation; validation
    windows are fixed by ``config.val_seed``. Batches are dicts of tensors in SI units (see
    ``WindowSource``); the model normalises them.
    """

    def __init__(self, config: TrainDataConfig, store: StoreData | None = None):
        super().__init__()
        self.config = config
        self.store = store
        self.source: WindowSource | None = None
        self.sims: SplitInfo | None = None
        self.normalization: Normalization | None = None
        self.val_uses_train = False

    @property
    def rate_hz(self) -> float:
        return self.store.rate_hz

    def setup(self, stage: str | None = None) -> None:
        if self.source is not None:
            return
        cfg = self.config
        if cfg.window < 1:
            raise ConfigError(f"config key 'data.window': must be at least 1 step, got {cfg.window}")
        if cfg.batch_size < 1:
            raise ConfigError(f"config key 'data.batch_size': must be at least 1, got {cfg.batch_size}")
        if self.store is None:
            self.store = load_store(cfg.store)
        n_avail = self.store.points.shape[1]
        if cfg.num_points is not None and not 1 <= cfg.num_points <= n_avail:
            raise ConfigError(
                f"config key 'data.num_points': {cfg.num_points} is not between 1 and the store's {n_avail} points"
            )
        if self.store.points_method == "hull_surface" and cfg.num_points is not None and cfg.num_points < n_avail:
            # a random subset drops hull vertices, the very points this representation keeps for contact
            raise ConfigError(
                f"config key 'data.num_points': {cfg.num_points} would subsample the store's {n_avail} hull_surface "
                f"points at random and lose hull vertices; set data.num_points=null, or simulate the store with "
                f"num_points={cfg.num_points}"
            )
        longest = int(np.max(np.diff(self.store.start)))
        if cfg.window >= longest:
            raise ConfigError(
                f"config key 'data.window': {cfg.window} steps is not shorter than the longest simulation in "
                f"{cfg.store} ({longest} steps); use fewer (e.g. {int(round(self.store.rate_hz))} = 1 s)"
            )
        points = cfg.num_points or n_avail
        batch_bytes = cfg.batch_size * (cfg.window * 4 * 64 + points * 3 * 4)  # ~64 floats per step, the cloud
        if batch_bytes > MAX_BATCH_BYTES:
            raise ConfigError(
                f"config key 'data.batch_size': a batch of {cfg.batch_size} windows of {cfg.window} steps and "
                f"{points} points needs about {batch_bytes / 2**30:.1f} GiB; lower data.batch_size or data.window"
            )
        pick = lambda split: select_sims(self.store, split, cfg.categories, cfg.exclude_categories)  # noqa: E731
        self.sims = SplitInfo(pick(0), pick(1), pick(2))
        if len(self.sims.train) == 0:
            raise ConfigError(
                f"config key 'data.store': {cfg.store} has no training simulations after category selection "
                f"(categories={list(cfg.categories)}, exclude_categories={list(cfg.exclude_categories)})"
            )
        self.source = WindowSource(self.store, cfg.window, cfg.num_points)
        self.normalization = compute_normalization(self.store, self.sims.train, self.source.targets, cfg.normalization)
        if len(self.sims.val) == 0:
            warnings.warn(
                f"{cfg.store} has no validation simulations; validating on fixed windows of the training "
                f"split instead (val/loss then measures fit, not generalisation)",
                stacklevel=2,
            )
            self.val_uses_train = True

    def _fixed_dataset(self, sims: np.ndarray) -> SimIndexDataset:
        reps = max(1, self.config.val_windows_per_sim)
        sims = np.repeat(sims, reps)
        rng = np.random.default_rng(self.config.val_seed)
        return SimIndexDataset(sims, self.source.random_starts(sims, rng))

    def _loader(self, dataset: Dataset, collate: WindowCollate, shuffle: bool, drop_last: bool) -> DataLoader:
        workers = self.config.num_workers
        return DataLoader(
            dataset,
            batch_size=self.config.batch_size,
            shuffle=shuffle,
            drop_last=drop_last,
            collate_fn=collate,
            num_workers=workers,
            persistent_workers=workers > 0,
        )

    def train_dataloader(self) -> DataLoader:
        ds = SimIndexDataset(self.sims.train)
        # Batch norm cannot train on a batch of one: drop a last batch of a single window (and only that, so
        # an epoch otherwise sees every training simulation once).
        drop = len(ds) > self.config.batch_size and len(ds) % self.config.batch_size == 1
        collate = WindowCollate(self.source, self.config.num_points, first_window_fraction=self.config.first_window_fraction,
                                yaw_augment=self.config.yaw_augment)
        return self._loader(ds, collate, True, drop)

    def val_dataloader(self) -> DataLoader:
        sims = self.sims.train if self.val_uses_train else self.sims.val
        collate = WindowCollate(self.source, self.config.num_points, fixed_seed=self.config.val_seed)
        return self._loader(self._fixed_dataset(sims), collate, False, False)

    def test_dataloader(self) -> DataLoader:
        collate = WindowCollate(self.source, self.config.num_points, fixed_seed=self.config.val_seed + 1)
        return self._loader(self._fixed_dataset(self.sims.test), collate, False, False)
