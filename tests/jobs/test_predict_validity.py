"""Every depth ``predict`` writes says which pixels and frames it could not estimate: the mask PNG, 0 in the 16-bit
PNG, NaN in the ``.npy`` on request, per-frame status and baseline in ``predictions.json``, NaN in the bag's 32FC1
depth (REP 118) read back with rosbags, and the status topic.

A stand-in model returns 20 m everywhere; the flight moves sideways 2 m, hovers two frames, moves again, so that
under the baseline policy (1 m) the statuses are reset, estimated, held, held, estimated, all by hand.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from PIL import Image

from cosemdepth.data.sequence import SequenceDataset, Trajectory
from cosemdepth.jobs.predict import predict
from cosemdepth.models import StepOutput, StreamState
from cosemdepth.models.config import ModelConfig
from cosemdepth.render.visualize import DEPTH_PNG_SCALE
from cosemdepth.streaming.sources.dataset import DatasetSource

H = W = 9
K = [8.0, 8.0, 4.5, 4.5]
MOTION = [(0, 0, 0), (2, 0, 0), (0, 0, 0), (0, 0, 0), (2, 0, 0)]  # previous -> current frame, metres
STATUSES = ["reset", "estimated", "held", "held", "estimated"]


class Plane(torch.nn.Module):
    """20 m everywhere; its depth state passes through when only the semantic decoder runs (as a model's does)."""

    decoders = ("depth", "semantic")

    def __init__(self):
        super().__init__()
        self.config = ModelConfig(arch="cosemdepth", num_classes=2)
        self.dummy = torch.nn.Parameter(torch.zeros(1))

    def step(self, rgb, rot, trans, intrinsics, reset, state, decoders=None):
        b = rgb.shape[0]
        run = decoders is None or "depth" in decoders
        depth = torch.full((b, 1, H, W), 20.0) if run else None
        probs = torch.nn.functional.one_hot(torch.zeros(b, H, W, dtype=torch.long), 2).permute(0, 3, 1, 2).float()
        heads = {"semantic": probs} if depth is None else {"depth": depth, "semantic": probs}
        return StepOutput(heads=heads), (StreamState(feat=(torch.zeros(b),)) if run or state is None else state)


def flight(n=len(MOTION)) -> SequenceDataset:
    traj = Trajectory(
        "hover", [str(k) for k in range(n)], np.tile([1.0, 0, 0, 0], (n, 1)), np.array(MOTION[:n]), np.arange(n)
    )
    return SequenceDataset([traj], lambda rec: {"rgb": torch.full((3, H, W), 0.5)}, torch.tensor(K), name="own")


class Stamped(DatasetSource):
    """The flight as a source whose frames carry their image header (as a bag's do: the output bag's stamps)."""

    def __init__(self, dataset, stamps):
        super().__init__(dataset)
        self.stamps = stamps

    def meta(self, trajectory, row):
        return {"stamp_ns": self.stamps[row], "frame_id": "cam"}


def run(tmp_path, invalid="keep", n=len(MOTION), stamps=None, **kw):
    out = tmp_path / "out"
    source = flight(n) if stamps is None else Stamped(flight(n), stamps)
    man = predict(Plane(), source, out, video=None, policy="baseline", min_baseline=1.0, invalid=invalid, **kw)
    return out, man


def png(path) -> np.ndarray:
    return np.asarray(Image.open(path))


def test_mask_png_zero_in_depth_png_and_status_per_frame(tmp_path):
    out, man = run(tmp_path)
    assert [f["status"] for f in man["frames"]] == STATUSES
    assert [f["baseline_m"] for f in man["frames"]] == [0.0, 2.0, 0.0, 0.0, 2.0]
    assert man["frames_by_status"] == {"reset": 1, "estimated": 2, "held": 2}
    assert man["policy"]["mode"] == "baseline" and man["policy"]["min_baseline_m"] == 1.0
    on_disk = json.loads((out / "predictions.json").read_text())
    assert on_disk["frames"] == man["frames"]
    for f in man["frames"]:
        mask = png(out / f["files"]["depth_valid"])
        depth16 = png(out / f["files"]["depth_png"])
        depth = np.load(out / f["files"]["depth"])
        assert mask.dtype == np.uint8 and set(np.unique(mask)) <= {0, 255}
        assert f["valid_fraction"] == pytest.approx((mask == 255).mean())
        # 0 in the 16-bit PNG exactly where the mask is 0; elsewhere the depth (20 m = 5120)
        assert ((depth16 == 0) == (mask == 0)).all()
        assert (depth16[mask == 255] == round(20.0 * DEPTH_PNG_SCALE)).all()
        assert np.isfinite(depth).all()  # --invalid keep: the values stay, the mask says which are estimates
    reset, est = man["frames"][0], man["frames"][1]
    assert (png(out / reset["files"]["depth_valid"]) == 0).all()  # a reset frame: nothing valid
    assert (png(out / est["files"]["depth_valid"]) == 255).all()  # sideways motion: all well conditioned
    for held in man["frames"][2:4]:  # the reference's depth and mask, carried without motion
        assert (png(out / held["files"]["depth_valid"]) == 255).all()
        assert (png(out / held["files"]["depth_png"]) == 5120).all()
    assert "depth_valid" in man["encodings"] and "0 where depth_valid is 0" in man["encodings"]["depth_png"]


def test_invalid_nan_writes_nan_where_the_mask_is_zero(tmp_path):
    out, man = run(tmp_path, invalid="nan")
    for f in man["frames"]:
        depth = np.load(out / f["files"]["depth"])
        mask = png(out / f["files"]["depth_valid"])
        assert (np.isnan(depth) == (mask == 0)).all()
    assert np.isnan(np.load(out / man["frames"][0]["files"]["depth"])).all()


def test_one_frame_flight_writes_no_valid_depth(tmp_path):
    out, man = run(tmp_path, n=1)
    (f,) = man["frames"]
    assert f["status"] == "reset" and f["valid_fraction"] == 0.0
    assert (png(out / f["files"]["depth_png"]) == 0).all() and (png(out / f["files"]["depth_valid"]) == 0).all()


def test_bad_invalid_mode_is_refused_before_anything_is_written(tmp_path):
    from cosemdepth.errors import ConfigError

    with pytest.raises(ConfigError, match="--invalid"):
        run(tmp_path, invalid="zero")
    assert not (tmp_path / "out").exists()


def test_bag_depth_is_nan_where_invalid_and_the_status_topic_reads_back(tmp_path):
    from rosbags.highlevel import AnyReader

    from cosemdepth.streaming.sinks.bag import BagSink

    stamps = [1_700_000_000_000_000_000 + k * 40_000_000 for k in range(len(MOTION))]
    sink = BagSink(K, palette=np.array([[0, 0, 0], [255, 255, 255]], np.uint8))
    out, man = run(tmp_path, sinks=(sink,), stamps=stamps)
    depth, valid, status = {}, {}, {}
    with AnyReader([out / "bag"]) as r:
        for c, t, raw in r.messages():
            msg = r.deserialize(raw, c.msgtype)
            if c.topic == "/cosemdepth/depth":
                assert msg.encoding == "32FC1"
                depth[t] = np.frombuffer(bytes(msg.data), "<f4").reshape(H, W)
            elif c.topic == "/cosemdepth/depth_valid":
                valid[t] = np.frombuffer(bytes(msg.data), np.uint8).reshape(H, W)
            elif c.topic == "/cosemdepth/depth_status":
                assert c.msgtype == "diagnostic_msgs/msg/DiagnosticArray"
                (st,) = msg.status
                status[t] = (st.message, int(st.level), {kv.key: kv.value for kv in st.values})
    assert sorted(depth) == stamps == sorted(status) == sorted(valid)
    for t, f in zip(stamps, man["frames"]):
        d = depth[t]
        assert (np.isnan(d) == (valid[t] == 0)).all()
        assert np.all(d[~np.isnan(d)] == 20.0)
        assert status[t][0] == f["status"] and status[t][2]["status"] == f["status"]
        assert float(status[t][2]["baseline_m"]) == pytest.approx(f["baseline_m"])
    assert np.isnan(depth[stamps[0]]).all()  # the reset frame: REP 118's "no measurement" everywhere
    assert [status[t][1] for t in stamps] == [2, 0, 1, 1, 0]  # ERROR reset, OK estimated, WARN held
    assert man["bag"]["topics"]["/cosemdepth/depth_status"] == "diagnostic_msgs/msg/DiagnosticArray"
