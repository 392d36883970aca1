"""Training data for ``python -m mepnet.train``: steps of manual folders, or manuals generated on
the fly in DataLoader workers. Both are deterministic functions of (seed, position), so a resumed
run sees exactly the samples an uninterrupted one would have seen.

- :class:`FolderSteps` + :class:`ResumableSampler` (a :class:`DistributedSampler` that starts
  part-way into an epoch): the sampler yields ``(index, epoch)`` keys; a sample's augmentation
  is drawn from ``(seed, epoch, index)``, whichever worker loads it.
- :class:`GeneratedSteps`: an infinite stream of collated batches. Batch ``g`` of rank ``r`` is
  made of stream positions ``g * B .. g * B + B - 1``; position ``j`` is slot ``j %
  samples_per_manual`` of the ``q = j // samples_per_manual``-th manual of rank ``r``, whose seed
  is ``seed_start + (q * world_size + r) mod (seed_end - seed_start)``. Ranks therefore never
  share a manual (until the seed range is exhausted and the stream wraps around, with fresh step
  choices and augmentation), and worker ``w`` of ``W`` produces batches ``g ≡ w (mod W)``, which
  the DataLoader hands out round-robin: the batch order does not depend on the number of
  workers, and resuming at step ``s`` is starting at batch ``s``.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np
import torch
from torch.utils.data import Dataset, DistributedSampler, IterableDataset, get_worker_info

from mepnet import _brickgeom as _bg
from mepnet.cli import quiet_interrupts_in_workers
from mepnet.detector.config import ModelConfig
from mepnet.detector.direct3d import add_translation_targets
from mepnet.detector.targets import StepSample, collate, make_sample
from mepnet.manual import (
    ComponentRef,
    Manual,
    answers_of,
    generated_manual,
    iter_manual_dirs,
    load_manual,
)

#: A step of a manual: (build key: a submodule index or None for the main model, step index).
StepKey = tuple[int | None, int]


def manual_steps(manual: Manual, submodules: bool) -> list[StepKey]:
    """The steps of the main build (and, with ``submodules``, of the submodules' builds)."""
    keys: list[StepKey] = [(None, s) for s in range(len(manual.main.steps))]
    if submodules:
        keys += [(k, s) for k, b in enumerate(manual.submodules) for s in range(len(b.steps))]
    return keys


def training_sample(
    manual: Manual,
    key: StepKey,
    cfg: ModelConfig,
    augment: bool,
    rng: np.random.Generator,
    components: dict[ComponentRef, _bg.Component] | None = None,
    styles: float = 0.0,
) -> StepSample:
    """Inputs and targets of a step on its true base shape (``components``: the manual's true
    components, when the caller keeps them); Direct3D's translations too when ``cfg.head`` is
    ``direct3d``. With probability ``styles`` the step is drawn again in a style drawn from
    ``rng`` (:func:`mepnet.styles.restyled_step`): the picture changes, the targets stay
    exact."""
    build, k = key
    answers = answers_of(manual)
    comps = components if components is not None else answers.components(manual)
    page = manual.main if build is None else manual.submodules[build]
    truth = answers.build(build)
    image = None
    # rng is only drawn from when styles are on: runs without them see the samples they did
    if styles > 0 and rng.random() < styles:
        from mepnet.styles import restyled_step

        image = restyled_step(manual, key, rng, comps)
    sample = make_sample(
        page.steps[k],
        cfg,
        base=truth.assembly_before(k, comps),
        components=comps,
        truth=truth.truth(k),
        augment=augment,
        rng=rng,
        image=image,
    )
    if cfg.head == "direct3d":
        return add_translation_targets(sample, page.steps[k], truth.truth(k), cfg)
    return sample


def worker_init(_worker_id: int) -> None:
    """DataLoader ``worker_init_fn``: one thread per worker for torch and the extension's pool
    (several workers already use the cores; set before the pool starts in this process)."""
    os.environ.setdefault("RAYON_NUM_THREADS", "1")
    torch.set_num_threads(1)
    quiet_interrupts_in_workers()


class FolderSteps(Dataset):
    """Steps of the manual folders under ``roots`` as training samples. Keys are ``(index,
    epoch)`` pairs (see :class:`ResumableSampler`); ``len`` is the number of steps."""

    def __init__(
        self,
        roots: Sequence[str | os.PathLike[str]],
        *,
        model_config: ModelConfig,
        seed: int,
        augment: bool,
        submodules: bool,
        styles: float = 0.0,
    ):
        self.manuals = [load_manual(p) for r in roots for p in iter_manual_dirs(r)]
        for m in self.manuals:
            answers_of(m)  # a clear error now for a manual without answers
        self.index = [
            (m, key) for m, man in enumerate(self.manuals) for key in manual_steps(man, submodules)
        ]
        self._components: dict[int, dict[ComponentRef, _bg.Component]] = {}
        self.model_config = model_config
        self.seed = seed
        self.augment = augment
        self.styles = styles

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, key: tuple[int, int]) -> StepSample:
        index, epoch = key
        m, step = self.index[index]
        manual = self.manuals[m]
        if m not in self._components:
            self._components[m] = answers_of(manual).components(manual)
        rng = np.random.default_rng([self.seed, epoch, index])
        return training_sample(
            manual, step, self.model_config, self.augment, rng, self._components[m], self.styles
        )


class ResumableSampler(DistributedSampler):
    """:class:`DistributedSampler` (shuffled per epoch from ``seed + epoch``, padded to equal
    shares per rank) that yields ``(index, epoch)`` and can skip the first ``skip`` indices of
    the epoch: a resumed run continues mid-epoch where the checkpoint was taken."""

    def __init__(self, dataset: Dataset, *, num_replicas: int, rank: int, seed: int):
        super().__init__(dataset, num_replicas=num_replicas, rank=rank, shuffle=True, seed=seed)
        self.skip = 0

    def __iter__(self) -> Iterator[tuple[int, int]]:  # type: ignore[override]
        indices = list(super().__iter__())[self.skip :]
        return iter([(int(i), self.epoch) for i in indices])

    def __len__(self) -> int:
        return super().__len__() - self.skip


class GeneratedSteps(IterableDataset):
    """Manuals generated on the fly (``_brickgeom.synth_manual``); yields collated batches
    forever, starting at batch ``start_batch`` (use with ``DataLoader(batch_size=None)``)."""

    def __init__(
        self,
        *,
        model_config: ModelConfig,
        seed: int,
        seed_range: tuple[int, int],
        generator: dict[str, Any],
        batch_size: int,
        samples_per_manual: int,
        augment: bool,
        submodules: bool,
        rank: int = 0,
        world_size: int = 1,
        start_batch: int = 0,
        styles: float = 0.0,
    ):
        if seed_range[1] <= seed_range[0]:
            raise ValueError(f"empty seed range {seed_range}")
        self.model_config = model_config
        self.seed = seed
        self.seed_range = seed_range
        self.generator = dict(generator)
        self.batch_size = batch_size
        self.samples_per_manual = samples_per_manual
        self.augment = augment
        self.submodules = submodules
        self.rank = rank
        self.world_size = world_size
        self.start_batch = start_batch
        self.styles = styles

    def manual_seed(self, q: int) -> tuple[int, int]:
        """Seed of this rank's ``q``-th manual and how many times the range wrapped before it."""
        start, end = self.seed_range
        lap, offset = divmod(q * self.world_size + self.rank, end - start)
        return start + offset, lap

    def batch(self, g: int) -> dict[str, torch.Tensor]:
        """Batch ``g`` of this rank (pure function of the settings and ``g``)."""
        k = self.samples_per_manual
        positions = range(g * self.batch_size, (g + 1) * self.batch_size)
        samples: list[StepSample] = []
        loaded: dict[int, tuple[Manual, list[StepKey], np.ndarray, int, int]] = {}
        for j in positions:
            q, slot = divmod(j, k)
            if q not in loaded:
                loaded[q] = self._manual(q)
            manual, steps, order, seed, lap = loaded[q]
            step = steps[order[slot % len(steps)]]
            rng = np.random.default_rng([self.seed, seed, lap, slot])
            samples.append(
                training_sample(
                    manual, step, self.model_config, self.augment, rng, styles=self.styles
                )
            )
        return collate(samples)

    def _manual(self, q: int) -> tuple[Manual, list[StepKey], np.ndarray, int, int]:
        seed, lap = self.manual_seed(q)
        generated = _bg.synth_manual(seed, self.generator)
        # held in memory: writing the pictures as PNG and reading them back was ~13% of a sample
        manual = generated_manual(generated, {"kind": "synthetic", "seed": seed})
        steps = manual_steps(manual, self.submodules)
        order = np.random.default_rng([self.seed, seed, lap]).permutation(len(steps))
        return manual, steps, order, seed, lap

    def __iter__(self) -> Iterator[dict[str, torch.Tensor]]:
        info = get_worker_info()
        worker, workers = (0, 1) if info is None else (info.id, info.num_workers)
        g = self.start_batch + worker
        while True:
            yield self.batch(g)
            g += workers
