"""The streaming pipeline through its public API only: a toy source and a toy sink registered in the tables, run by
``streaming.run`` with a Streamer over a small real model; their frames, outputs, state and summaries."""

from __future__ import annotations

from dataclasses import dataclass, field

import pytest
import torch

from cosemdepth import Streamer, build_model
from cosemdepth.errors import NonFiniteOutputError
from cosemdepth.streaming import SINKS, SOURCES, FrameBatch, Sink, Source, StreamBatch, register_sink, register_source
from cosemdepth.streaming import run as run_stream

H = W = 16
K = torch.tensor([8.0, 8.0, 8.0, 8.0])


def toy_frames(n: int, seed: int = 0) -> list[dict]:
    """``n`` random frames of one trajectory moving 1 m forward per frame."""
    g = torch.Generator().manual_seed(seed)
    return [
        {
            "rgb": torch.rand(3, H, W, generator=g),
            "rot": torch.tensor([1.0, 0.0, 0.0, 0.0]),
            "trans": torch.tensor([0.0, 0.0, 0.0 if i == 0 else 1.0]),
        }
        for i in range(n)
    ]


@dataclass(frozen=True)
class ToyOptions:
    """The toy source's options, as a command would build them."""

    lengths: tuple = (3, 2)
    source = "toy"

    def inputs(self) -> list:
        return []


class ToySource:
    """Trajectories of random frames, one lane per trajectory; its frames are named and stamped."""

    name = "toy"

    def __init__(self, lengths=(3, 2)) -> None:
        self.trajs = {f"t{k}": toy_frames(n, seed=k) for k, n in enumerate(lengths)}
        self.closed = False

    @classmethod
    def from_options(cls, options: ToyOptions, size=None):
        return cls(options.lengths)

    def describe(self) -> dict:
        return {"name": "toy", "trajectories": len(self.trajs)}

    def frame_size(self):
        return (H, W)

    def batches(self, *, lanes=1, max_frames=None, num_workers=0):
        names = list(self.trajs)
        longest = max(len(f) for f in self.trajs.values())
        index = 0
        for row in range(longest):
            live = [k for k in range(min(lanes, len(names))) if row < len(self.trajs[names[k]])]
            frames = [self.trajs[names[k]][row] for k in live]
            idx = list(range(index, index + len(live)))
            index += len(live)
            yield FrameBatch(
                rgb=torch.stack([f["rgb"] for f in frames]),
                rot=torch.stack([f["rot"] for f in frames]),
                trans=torch.stack([f["trans"] for f in frames]),
                intrinsics=K.repeat(len(live), 1),
                reset=torch.tensor([row == 0] * len(live)),
                trajectory=[names[k] for k in live],
                frame=torch.full((len(live),), row, dtype=torch.int64),
                index=idx,
                lanes=tuple(live),
                name=[f"{names[k]}#{row:03d}" for k in live],
                stamp=[row * 0.5 for _ in live],
                meta=[{"lane": k} for k in live],
            )

    def close(self) -> None:
        self.closed = True


@dataclass
class ToySink:
    """Keeps every batch; says how many frames it saw."""

    opened: object = "not yet"
    batches: list = field(default_factory=list)
    aborted: bool = False

    def open(self, folder) -> None:
        self.opened = folder

    def __call__(self, batch: StreamBatch) -> None:
        self.batches.append(batch)

    def close(self) -> dict:
        return {"toy_frames": sum(len(b) for b in self.batches)}

    def abort(self) -> None:
        self.aborted = True


@pytest.fixture(scope="module")
def model():
    torch.manual_seed(0)
    return build_model(arch="cosemdepth", levels=2, num_classes=3).eval()


@pytest.fixture(autouse=True)
def tables():
    register_source("toy", ToySource)
    register_sink("toy", ToySink)
    yield
    SOURCES.pop("toy")
    SINKS.pop("toy")


def test_a_toy_source_and_sink_through_the_pipeline(model, tmp_path):
    source = SOURCES["toy"].from_options(ToyOptions((3, 2)))
    sink = SINKS["toy"]()
    assert isinstance(source, Source) and isinstance(sink, Sink)
    summary = run_stream(source, Streamer(model, "every-frame"), [sink], lanes=2, out=tmp_path)
    assert summary == {"toy_frames": 5} and sink.opened == tmp_path and source.closed and not sink.aborted
    assert [b.trajectory for b in sink.batches] == [["t0", "t1"], ["t0", "t1"], ["t0"]]
    assert [b.name for b in sink.batches][2] == ["t0#002"] and sink.batches[1].stamp == [0.5, 0.5]
    assert [b.meta for b in sink.batches][0] == [{"lane": 0}, {"lane": 1}]
    assert [b.status for b in sink.batches] == [["reset", "reset"], ["estimated", "estimated"], ["estimated"]]
    # each trajectory's outputs are those of the model streaming it alone (the state flows per lane, and is sliced
    # when lane 1 ends)
    for k, traj in enumerate(ToySource((3, 2)).trajs.values()):
        ref = model.infer(
            torch.stack([f["rgb"] for f in traj]),
            (torch.stack([f["rot"] for f in traj]), torch.stack([f["trans"] for f in traj])),
            K,
        )
        got = torch.stack([b.depth[b.lanes.index(k)] for b in sink.batches if k in b.lanes])
        torch.testing.assert_close(got[1:], ref.depth[1:], rtol=1e-5, atol=1e-5)
        labels = torch.stack([b.labels[b.lanes.index(k)] for b in sink.batches if k in b.lanes])
        assert torch.equal(labels, ref.semantic.argmax(1))


def test_a_failing_step_aborts_every_sink_and_closes_the_source(model):
    class Broken(torch.nn.Module):
        config = model.config
        decoders = model.decoders

        def __init__(self):
            super().__init__()
            self.p = torch.nn.Parameter(torch.zeros(1))

        def step(self, *args, **kwargs):
            out, state = model.step(*args, **kwargs)
            out.heads["semantic"] = out.heads["semantic"] * float("nan")
            return out, state

    source, sinks = ToySource((2,)), [ToySink(), ToySink()]
    with pytest.raises(NonFiniteOutputError, match=r"t0#000 \(dataset row 0, trajectory t0, frame 0\)"):
        run_stream(source, Streamer(Broken(), "every-frame"), sinks)
    assert all(s.aborted for s in sinks) and source.closed


def test_a_toy_source_and_sink_through_predict(model, tmp_path):
    """predict's library entry point takes any registered source and further sinks: the files of every frame are
    named from the frames' names, their metadata lands in predictions.json, the toy sink's summary too."""
    import json

    import numpy as np

    from cosemdepth.jobs.predict import predict

    sink = SINKS["toy"]()
    out = tmp_path / "pred"
    man = predict(
        model,
        SOURCES["toy"].from_options(ToyOptions((3, 2))),
        out,
        sinks=[sink],
        video=None,
        lanes=2,
        policy="every-frame",
    )
    assert man["toy_frames"] == 5 == man["frames_written"] and sink.opened != out  # written into the staging folder
    assert json.loads((out / "predictions.json").read_text())["toy_frames"] == 5
    frames = {(f["trajectory"], f["frame"]): f for f in man["frames"]}
    assert frames["t1", 1]["source"] == "t1#001" and frames["t1", 1]["lane"] == 1
    assert frames["t0", 2]["files"]["depth"] == "t0/depth/t0_002.npy"  # the stem of the frame's name
    # the written depth is the one the sink saw
    (batch,) = [b for b in sink.batches if 2 in b.frame.tolist()]
    np.testing.assert_array_equal(np.load(out / "t0" / "depth" / "t0_002.npy"), batch.depth[0, 0].numpy())


def test_a_toy_source_through_the_predict_command_s_options(model, tmp_path):
    """run_predict (what ``cosemdepth predict`` runs once its arguments are parsed) opens a source by its table
    entry, from its options."""
    from cosemdepth import save_model
    from cosemdepth.jobs.model import ModelOptions
    from cosemdepth.jobs.options import RunOptions
    from cosemdepth.jobs.predict import PredictOptions, run_predict
    from cosemdepth.streaming.sinks.files import FileOptions

    folder = save_model(model, tmp_path / "m")
    options = PredictOptions(
        source=ToyOptions(),
        model=ModelOptions(folder, reference=True, device="cpu"),
        out=tmp_path / "pred",
        run=RunOptions(lanes=2, policy="every-frame"),
        files=FileOptions(video=None),
    )
    result = run_predict(options)
    man = result.manifest
    assert man["dataset"] == {"name": "toy", "trajectories": 2} and man["run"]["input_size"] == [H, W]
    assert man["frames_written"] == 5 and [t["name"] for t in man["trajectories"]] == ["t0", "t1"]
    assert result.lines[0] == f"wrote 5 frames of 2 trajectories to {tmp_path / 'pred'}"


class UnusableMotion(ToySource):
    """The toy trajectory whose frame 1 has a motion the source cannot vouch for (attitude only); its positions are
    known to 3 m."""

    min_baseline_m = 3.0

    def batches(self, **kw):
        for b in super().batches(**kw):
            b.depth_ok = b.frame != 1
            b.meta = [{"depth_invalid_reason": "attitude only"} if f == 1 else {} for f in b.frame.tolist()]
            yield b


def test_a_frame_without_a_usable_motion_has_no_depth_and_restarts_the_reference(model):
    sink = ToySink()
    run_stream(UnusableMotion((4,)), Streamer(model, "every-frame"), [sink])
    assert [b.status[0] for b in sink.batches] == ["reset", "reset", "estimated", "estimated"]
    assert [bool(b.reset[0]) for b in sink.batches] == [True, True, False, False]
    assert not sink.batches[1].valid.any() and sink.batches[1].meta[0]["depth_invalid_reason"] == "attitude only"
    assert float(sink.batches[2].baseline[0]) == 1.0  # estimated from frame 1


def test_the_source_s_baseline_floor_raises_the_policy_s_minimum(model):
    from cosemdepth.jobs.predict import make_streamer

    assert make_streamer(model, "baseline", 1.0, UnusableMotion((2,))).min_baseline == 3.0
    assert make_streamer(model, "baseline", 5.0, UnusableMotion((2,))).min_baseline == 5.0
    assert make_streamer(model, "baseline", 1.0, ToySource((2,))).min_baseline == 1.0
    assert make_streamer(model, "every-frame", None, UnusableMotion((2,))).min_baseline == 0.0


class CoarsePositions(ToySource):
    """The toy trajectory (1 m per frame) from positions that resolve 2.5 m."""

    min_baseline_m = 2.5


@pytest.mark.parametrize("policy", ["every-frame", "baseline"])
def test_no_depth_is_valid_on_a_baseline_the_positions_cannot_measure(model, policy):
    from cosemdepth.jobs.predict import make_streamer

    sink = ToySink()
    source = CoarsePositions((6,))
    run_stream(source, make_streamer(model, policy, 1.0 if policy == "baseline" else None, source), [sink])
    status = [b.status[0] for b in sink.batches]
    base = [float(b.baseline[0]) for b in sink.batches]
    if policy == "every-frame":  # every frame estimated from the previous one, 1 m away
        assert status == ["reset"] + ["estimated"] * 5 and base[1:] == [1.0] * 5
    else:  # the minimum raised to 2.5 m: frame 3 estimated from frame 0 (1, 2: no depth yet), 4 and 5 hold its depth
        assert status == ["reset"] * 3 + ["estimated", "held", "held"] and base == [0, 1, 2, 3, 1, 2]
    for b, s, d in zip(sink.batches, status, base):
        if s != "reset" and d < 2.5:
            assert not b.valid.any() and "less than 2.5 m from its reference" in b.meta[0]["depth_invalid_reason"]
        else:
            assert "depth_invalid_reason" not in b.meta[0]


def test_a_floor_below_every_baseline_changes_nothing(model):
    class FinePositions(ToySource):
        min_baseline_m = 0.5

    runs = []
    for source in (ToySource((6,)), FinePositions((6,))):
        sink = ToySink()
        run_stream(source, Streamer(model, "baseline", min_baseline=2.5), [sink])
        runs.append(sink.batches)
    assert [b.status[0] for b in runs[0]] == ["reset"] * 3 + ["estimated", "held", "held"]
    for plain, fine in zip(*runs):
        assert torch.equal(plain.valid, fine.valid) and "depth_invalid_reason" not in fine.meta[0]
