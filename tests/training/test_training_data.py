"""Training data plumbing: the resumable distributed sampler, collation, the toy dataset, dataset errors, pictures."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader, DistributedSampler

from cosemdepth.data import MixedDataset
from cosemdepth.data.midair.format import PALETTE_7
from cosemdepth.data.toy import ToyDataset
from cosemdepth.decoders.depth import DEPTH
from cosemdepth.decoders.semantic import SEMANTIC
from cosemdepth.errors import ConfigError, DatasetError
from cosemdepth.models.config import ModelConfig
from cosemdepth.render.examples import depth_to_rgb, example_strip, labels_to_rgb
from cosemdepth.training.config import DataConfig, DatasetSource
from cosemdepth.training.data import (
    EpochBatchSampler,
    EpochItems,
    ResumableSampler,
    build_train_dataset,
    check_modalities,
    collate,
    make_train_stream,
    open_source,
    steps_per_epoch,
    total_steps,
)


def test_sampler_matches_distributed_sampler_and_resumes_mid_epoch():
    data = list(range(11))
    ref = DistributedSampler(data, num_replicas=1, rank=0, shuffle=True, seed=5, drop_last=True)
    ref.set_epoch(3)
    s = ResumableSampler(data, seed=5)
    s.set_position(3)
    full = list(s)
    assert full == list(ref) and sorted(full) == data
    s.set_position(3, start=4)
    assert list(s) == full[4:] and len(s) == 7
    s.set_position(4)
    assert list(s) != full  # a new order every epoch
    s.set_position(3, salt=1)
    assert list(s) != full and sorted(s) == data  # a rollback re-shuffles


def test_two_ranks_split_the_single_process_order():
    """Batch k of two ranks with batch B together hold batch k of one process with batch 2B."""
    data = list(range(12))
    single = ResumableSampler(data, seed=1)
    single.set_position(0)
    ranks = [ResumableSampler(data, num_replicas=2, rank=r, seed=1) for r in (0, 1)]
    for r in ranks:
        r.set_position(0)
    order = list(single)
    r0, r1 = list(ranks[0]), list(ranks[1])
    b = 2
    for k in range(len(r0) // b):
        assert sorted(r0[k * b : (k + 1) * b] + r1[k * b : (k + 1) * b]) == sorted(order[2 * b * k : 2 * b * (k + 1)])
    assert steps_per_epoch(data, 2, 2) == 3 and steps_per_epoch(data, 4, 1) == 3
    assert total_steps(60, 3, 0) == 180 and total_steps(60, 3, 7) == 7


def test_collate_stacks_tensors_and_lists_the_rest():
    items = [{"rgb": torch.zeros(4, 3, 2, 2), "trajectory": "a"}, {"rgb": torch.ones(4, 3, 2, 2), "trajectory": "b"}]
    b = collate(items)
    assert b["rgb"].shape == (2, 4, 3, 2, 2) and b["trajectory"] == ["a", "b"] and b["rgb"][1].min() == 1


def test_toy_dataset_layout_and_motion():
    ds = ToyDataset(length=3, seq_len=4, size=(16, 24), num_classes=5, seed=1, shift=2)
    it = ds[1]
    assert it["rgb"].shape == (4, 3, 16, 24) and it["depth"].shape == (4, 1, 16, 24)
    assert it["semantic"].shape == (4, 16, 24) and it["semantic"].dtype == torch.int64
    assert int(it["semantic"].max()) < 5 and it["reset"].tolist() == [True, False, False, False]
    assert torch.equal(ds[1]["rgb"], it["rgb"])  # deterministic
    assert not torch.equal(ToyDataset(length=3, seed=1, split="val")[1]["rgb"], ToyDataset(length=3, seed=1)[1]["rgb"])
    # the content slides left by `shift` pixels per frame, matching t = (shift * altitude / f, 0, 0)
    assert torch.equal(it["rgb"][1, :, :, :-2], it["rgb"][0, :, :, 2:])
    f = float(it["intrinsics"][0])
    assert f == 12.0 and torch.allclose(it["trans"][1], torch.tensor([2 * 40.0 / f, 0.0, 0.0]))
    # depth follows the class: one depth per label
    d, lab = it["depth"][0, 0], it["semantic"][0]
    for c in lab.unique():
        assert d[lab == c].unique().numel() == 1


def _open(src, **kw):
    args = dict(
        split="train", seq_len=4, size=(32, 32), augment=False, mode="train", db_seq_len=4, seed=0, num_classes=7
    )
    args.update(kw)
    return open_source(src, "data.train[0]", **args)


def test_the_toy_opens_through_the_dataset_table_with_the_run_seed_and_the_model_classes():
    ds = _open(
        DatasetSource(name="toy", options={"length": 3, "shift": 1}),
        split="val",
        seq_len=3,
        size=(16, 24),
        seed=5,
        num_classes=4,
    )
    expected = ToyDataset(length=3, seq_len=3, size=(16, 24), num_classes=4, seed=5, split="val", shift=1)
    assert len(ds) == 3
    for k in ("rgb", "depth", "semantic", "trans"):
        assert torch.equal(ds[2][k], expected[2][k]), k
    with pytest.raises(
        ConfigError,
        match=r"data\.train\[0\] \(toy, split 'train'\): unknown option\(s\) \['colour'\] "
        r"for dataset 'toy'",
    ):
        _open(DatasetSource(name="toy", options={"colour": 1}))


def test_dataset_errors_name_the_key_and_the_folder(tmp_path):
    with pytest.raises(DatasetError, match=r"data\.train\[0\]\.root: dataset folder .*nowhere not found"):
        _open(DatasetSource(name="synthair", root=str(tmp_path / "nowhere")))
    (tmp_path / "file").write_text("x")
    with pytest.raises(DatasetError, match="is not a folder"):
        _open(DatasetSource(name="midair", root=str(tmp_path / "file")))
    with pytest.raises(DatasetError, match=r"split_dir: split folder"):
        _open(DatasetSource(name="midair", root=str(tmp_path), split_dir=str(tmp_path / "no_splits")))
    with pytest.raises(ConfigError, match=r"data\.train\[0\]\.root: the folder of the 'topair' dataset is required"):
        _open(DatasetSource(name="topair"))
    with pytest.raises(ConfigError, match="unknown option"):
        _open(DatasetSource(name="toy", options={"colour": 1}))


def test_modalities_are_checked_against_the_model():
    class NoDepth(ToyDataset):
        def __getitem__(self, i):
            item = super().__getitem__(i)
            del item["depth"]
            return item

    check_modalities(NoDepth(length=1), ModelConfig(arch="m4semantic"), "x")
    with pytest.raises(DatasetError, match="no depth ground truth.*m4semantic"):
        check_modalities(NoDepth(length=1), ModelConfig(arch="cosemdepth"), "the training data")


def test_an_empty_training_set_is_an_error():
    data = DataConfig(train=(DatasetSource(name="toy", options={"length": 0}),), size=(32, 32))
    with pytest.raises(DatasetError, match=r"data\.train\[0\] \(toy, split 'train'\) has no training sequence"):
        build_train_dataset(data, ModelConfig(levels=3), 0)


def test_pictures():
    pal = labels_to_rgb(np.array([[0, 1], [6, 9]]), 7)
    assert (pal[0, 0] == PALETTE_7[0]).all() and (pal[1, 0] == PALETTE_7[6]).all() and (pal[1, 1] == 0).all()
    near, far = depth_to_rgb(np.array([[1.0, 150.0]]))[0]
    assert int(near.sum()) > int(far.sum())  # near is brighter
    assert (depth_to_rgb(np.array([[np.nan]])) == 0).all()
    example = {
        "depth": torch.ones(1, 8, 8),
        "pred_depth": torch.ones(1, 8, 8),
        "semantic": torch.zeros(8, 8, dtype=torch.long),
    }
    cfg = ModelConfig()
    panels = DEPTH.strip_panels(example, cfg) + SEMANTIC.strip_panels(example, cfg)  # no predicted labels: 3 panels
    strip = example_strip(torch.rand(3, 8, 8), panels)
    assert strip.shape == (8, 32, 3) and strip.dtype == np.uint8
    assert (strip[:, 8:16] == depth_to_rgb(np.ones((8, 8)))).all() and (strip[:, 24:] == PALETTE_7[0]).all()


class _EpochItems(torch.utils.data.Dataset):
    """Items that name the epoch selected by ``set_epoch`` and their index."""

    def __init__(self, n: int, tag: int) -> None:
        self.n, self.tag, self.epoch = n, tag, 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, i: int) -> dict:
        return {"v": torch.tensor([self.tag, self.epoch, i])}


def _old_batches(dataset, *, epoch, start_batch, salt, batch_size, epochs, num_replicas=1, rank=0):
    """The batches of one DataLoader per epoch, as the trainer built them before the continuous stream."""
    sampler = ResumableSampler(dataset, num_replicas=num_replicas, rank=rank, seed=9)
    out = []
    for e in range(epoch, epoch + epochs):
        dataset.set_epoch(e)
        sampler.set_position(e, (start_batch if e == epoch else 0) * batch_size, salt)
        loader = DataLoader(dataset, batch_size=batch_size, sampler=sampler, drop_last=True, collate_fn=collate)
        out += [b["v"] for b in loader]
    return out


@pytest.mark.parametrize("num_workers", [0, 2])
@pytest.mark.parametrize("mixed", [False, True])
def test_continuous_stream_gives_the_batches_of_one_loader_per_epoch(num_workers, mixed):
    """From batch 1 of epoch 2 with a salted order, over the rest of epoch 2 and epochs 3 and 4: 11 items, batch 3
    (3 full batches per epoch, 2 items dropped). The items follow the epochs also in long-lived workers."""

    def data():
        if mixed:
            return MixedDataset([_EpochItems(7, 0), _EpochItems(5, 1)], [1.0, 2.0], length=11, seed=4)
        return _EpochItems(11, 0)

    expected = _old_batches(data(), epoch=2, start_batch=1, salt=1, batch_size=3, epochs=3)
    assert len(expected) == 2 + 3 + 3
    ds = data()
    stream = make_train_stream(
        ds, ResumableSampler(ds, seed=9), 3, num_workers, epoch=2, start_batch=1, salt=1, num_batches=8, seed=0
    )
    got = [b["v"] for b in stream]
    assert len(got) == 8 and all(torch.equal(g, e) for g, e in zip(got, expected))
    assert [int(b[0, 1]) for b in got] == [2, 2, 3, 3, 3, 4, 4, 4]  # (a mix passes its epoch on)


def test_continuous_stream_of_one_rank_and_an_endless_stream():
    ds = _EpochItems(13, 0)
    expected = _old_batches(ds, epoch=0, start_batch=0, salt=0, batch_size=2, epochs=3, num_replicas=2, rank=1)
    assert len(expected) == 3 * 3  # 6 items per rank and epoch
    sampler = ResumableSampler(ds, num_replicas=2, rank=1, seed=9)
    batches = EpochBatchSampler(sampler, 2, epoch=0, num_batches=None)
    got = []
    for b in batches:  # endless: the consumer stops
        got.append(torch.stack([EpochItems(ds)[k]["v"] for k in b]))
        if len(got) == len(expected):
            break
    assert all(torch.equal(g, e) for g, e in zip(got, expected))
    with pytest.raises(ValueError, match="no full batch"):
        next(iter(EpochBatchSampler(ResumableSampler(ds, seed=0), 14, epoch=0)))
