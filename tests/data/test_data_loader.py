"""DataLoader factory (seeded shuffling, workers independent of results) and the weighted dataset mix."""

from __future__ import annotations

import pytest
import torch
from _writers import write_midair

from cosemdepth.data import MixedDataset, collate, make_loader, open_dataset
from cosemdepth.data.midair.splits import generate_splits
from cosemdepth.errors import ConfigError


@pytest.fixture(scope="module")
def roots(tmp_path_factory):
    base = tmp_path_factory.mktemp("loader")
    write_midair(base / "a", {("Kite_training", "sunny"): [0, 1, 2, 4, 5]}, frames=20, size=16)
    generate_splits(base / "a", base / "a_splits")
    write_midair(base / "b", {("SynthAir", "cloudy"): [0, 1, 2]}, frames=20, size=16, seed=1)
    generate_splits(base / "b", base / "b" / "splits")
    return base


def train_set(roots, **kw):
    return open_dataset(
        "midair",
        roots / "a",
        split_dir=roots / "a_splits",
        split="train",
        seq_len=2,
        db_seq_len=4,
        size=8,
        augment=True,
        **kw,
    )


def batches(loader):
    return [b for b in loader]


def test_workers_do_not_change_the_batches_and_epochs_reshuffle(roots):
    ds = train_set(roots)
    assert len(ds) == 3  # indices 1, 2, 4 of 0..4
    single = make_loader(ds, batch_size=2, shuffle=True, num_workers=0, seed=7)
    multi = make_loader(train_set(roots), batch_size=2, shuffle=True, num_workers=2, seed=7)
    e0, e1 = batches(single), batches(single)
    m0, m1 = batches(multi), batches(multi)
    for a, b in zip(e0 + e1, m0 + m1):
        assert a.keys() == b.keys()
        for k in a:
            if isinstance(a[k], torch.Tensor):
                assert torch.equal(a[k], b[k]), k
            else:
                assert a[k] == b[k]
    assert e0[0]["rgb"].shape == (2, 2, 3, 8, 8) and e0[0]["reset"].tolist() == [[True, False]] * 2
    order = lambda bs: [t for b in bs for t in b["trajectory"]]  # noqa: E731
    assert sorted(order(e0)) == sorted(order(e1))
    assert not all(torch.equal(a["rgb"], b["rgb"]) for a, b in zip(e0, e1))  # new draws each epoch
    single.set_epoch(0)
    again = batches(single)
    assert all(torch.equal(a["rgb"], b["rgb"]) for a, b in zip(e0, again))


def test_unshuffled_loader_keeps_the_stream_order(roots):
    ds = open_dataset("midair", roots / "a", split_dir=roots / "a_splits", split="test", seq_len=1, size=8)
    got = [(t, int(f)) for b in make_loader(ds, batch_size=3) for t, f in zip(b["trajectory"], b["frame"][:, 0])]
    assert got == [(ds[i]["trajectory"], int(ds[i]["frame"][0])) for i in range(len(ds))]


def test_weighted_mix(roots):
    a = train_set(roots)
    b = open_dataset("synthair", roots / "b", split="train", seq_len=2, db_seq_len=4, size=8, augment=True)
    only_a = MixedDataset([a, b], [1.0, 0.0], length=20, seed=1)
    assert {int(only_a[i]["source"]) for i in range(20)} == {0}
    mix = MixedDataset([a, b], [1.0, 3.0], length=400, seed=1)
    picks = [mix.pick(i)[0] for i in range(400)]
    assert 0.65 < sum(picks) / 400 < 0.85
    assert mix[5].keys() == a[0].keys() | {"source"}
    assert torch.equal(mix[5]["rgb"], mix[5]["rgb"])
    batch = next(iter(make_loader(mix, batch_size=4, shuffle=True)))
    assert batch["rgb"].shape == (4, 2, 3, 8, 8) and batch["source"].shape == (4,)
    with pytest.raises(ConfigError):
        MixedDataset([a, b], [1.0])
    with pytest.raises(ConfigError):
        MixedDataset([a, b], [0.0, 0.0])


def test_collate_rejects_mismatched_items():
    with pytest.raises(ValueError, match="different keys"):
        collate([{"rgb": torch.zeros(1)}, {"rgb": torch.zeros(1), "depth": torch.zeros(1)}])
    with pytest.raises(ConfigError):
        make_loader([], batch_size=0)
