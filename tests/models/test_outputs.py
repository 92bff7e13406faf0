"""The output and state containers are keyed by name: ``depth``, ``semantic``, ``labels`` (and the state's
``features``/``depths``, the sequence's ``depth``/``semantic``) only read the keyed dicts, and ``labels`` is the
argmax over the class axis whatever the rank."""

import pytest
import torch

from cosemdepth.models import SequenceOutput, StepOutput, StreamState


def test_step_output_reads_its_heads_and_labels_take_the_class_axis():
    probs = torch.zeros(2, 3, 4, 5)
    probs[0, 2] = 1.0  # sample 0: class 2 everywhere
    probs[1, 1, :, :2] = 1.0  # sample 1: class 1 on the first two columns, else class 0 (all zero: the first)
    depth = torch.full((2, 1, 4, 5), 7.0)
    out = StepOutput(heads={"depth": depth, "semantic": probs, "edge": depth})
    assert out.depth is depth and out.semantic is probs
    want = torch.zeros(2, 4, 5, dtype=torch.long)
    want[0] = 2
    want[1, :, :2] = 1
    assert out.labels.dtype == torch.int64 and torch.equal(out.labels, want)
    # a sequence of them ([B, T, N, H, W], as infer stacks frames): the class axis, not the frames
    seq = StepOutput(heads={"semantic": torch.stack([probs, probs.flip(0)], 1)})
    assert seq.labels.shape == (2, 2, 4, 5)
    assert torch.equal(seq.labels[:, 0], want) and torch.equal(seq.labels[:, 1], want.flip(0))
    # one sequence without a batch ([T, N, H, W])
    assert torch.equal(StepOutput(heads={"semantic": probs}).labels, want)


def test_the_named_outputs_are_read_only_and_absent_heads_are_none():
    out = StepOutput(heads={"semantic": torch.rand(1, 3, 2, 2)})
    assert out.depth is None and StepOutput().labels is None and StepOutput().semantic is None
    with pytest.raises(AttributeError):
        out.depth = torch.ones(1, 1, 2, 2)
    out.heads["depth"] = torch.ones(1, 1, 2, 2)  # a change goes through the keyed dict
    assert torch.equal(out.depth, torch.ones(1, 1, 2, 2))


def test_stream_state_components_by_name():
    f, d = (torch.zeros(1, 4, 2, 2),), (torch.ones(1, 1, 2, 2),)
    a = StreamState(feat=f, depth=d)
    assert a == StreamState({"feat": f, "depth": d}) and a.features == f and a.depths == d
    assert list(StreamState(semantic=d, feat=()).components) == ["semantic"]  # empty components are left out
    with pytest.raises(TypeError, match="by name"):
        StreamState(f)  # the features alone, as a positional argument
    with pytest.raises(TypeError):
        StreamState(f, d)
    with pytest.raises(AttributeError):
        a.depths = d


def test_sequence_output_levels_by_key():
    maps = [torch.rand(1, 2, 1, 4, 4)]
    seq = SequenceOutput(levels={"depth": maps, "edge": maps})
    assert seq.depth is maps and seq.semantic == [] and seq.maps("edge") is maps
    with pytest.raises(KeyError, match=r"'parallax'.*\['depth', 'edge'\]"):
        seq.maps("parallax")
