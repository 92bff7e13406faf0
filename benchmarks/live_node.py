"""End-to-end latency, sustained rate and dropped frames of ``cosemdepth node`` on a replayed SynthAir flight.

    python benchmarks/live_node.py --model weights/synthair-cosemdepth --flight DIR [--frames 200]
        [--rates 10 20 30] [--sizes own 384] [--modes fast-fp32 fast-bf16 onnx-int8] [--threads N ...]
        [--memory-minutes 10] [--out benchmarks/results/live_node.json]
    python benchmarks/live_node.py --flight DIR --acceptance     # own size, fast fp32, 10 and 30 Hz, 2 min memory,
                                                                 # the threads side by side

``DIR`` is a SynthAir root (``cosemdepth synth --out DIR --trajectories 1 --frames 804 --size 384 --climates sunny``:
200 images of 384x384 at 6.25 Hz); its first trajectory becomes a ROS 2 bag (``/camera/image_raw`` rgb8,
``/camera/camera_info``, 100 Hz ``/odom`` PoseStamped, NED body). Everything runs on this machine: Cyclone DDS bound
to the loopback interface, no multicast, unicast discovery on 127.0.0.1, a domain of its own.

For each size (``own``: the model's focal length, no ``--size``; or N) and mode (``fast-fp32``, ``fast-bf16``: the
fast path's precisions; ``onnx-int8``: ``cosemdepth export --int8`` at that size, run by ONNX Runtime) and thread
count (``--threads``; default the node's own: every core, OpenMP threads that sleep while they wait) one node runs;
a warm-up replay of the first 30 frames, then for each rate the whole flight is replayed
(``cosemdepth replay --rate rate/6.25``) and a subscriber in this process records:

* latency: from the replay writing an image (its DDS source timestamp) to this subscriber taking the node's depth for
  that image (p50 / p95 / max, ms), the node's own figure (image written -> outputs handed to DDS, from its status)
  and, from the node's status, the model's streaming step within it (``model_step_ms``), the image's wait for the
  model (``queue_ms``), its conversion (``convert_ms``) and the rest, the node's own time (``node_overhead_ms``:
  delivery to the node, conversion, publishing); per frame, the step's share of the end-to-end and of the node's
  latency (``step_over_latency``, ``step_over_node_latency``: p50 and p5, one run);
* drops: the node's counters (its status topic) over the replay: images received, processed, dropped; images that
  never reached it (published minus received);
* at the highest rate, ``equal_to_predict_bag``: the node's depth messages equal, byte for byte, those of
  ``predict --bag`` (same model, mode, size and threads) on a bag of exactly the frames the node processed (with every
  pose): dropped frames change the motion chain, so the reference is the chain the node ran (the node runs with
  ``--max-frame-gap 30``: a replay faster than recorded stretches the stamps between processed frames).

``sustained_hz``: the node's processing rate at the highest input rate (processed frames / replay seconds);
``max_rate_without_drops_hz``: the highest tested rate with no dropped frame. ``--memory-minutes M``: the first
size and mode also run the flight in a loop at the highest rate for M minutes, the node's resident memory sampled
every 5 s (``flat`` when it grows by less than ``--tolerance-mb`` after the first minute). A mode that cannot run
here (bf16 without CPU bf16 dot products: no ``avx512_bf16`` / ``amx_bf16`` flag) is recorded as not run, with the
reason. With 10 and 30 Hz among the rates each configuration gets ``acceptance``: no dropped frame at 10 Hz (and
its p95 latency), the drops at 30 Hz and the depth equal to ``predict --bag``'s there, memory flat (when measured).
``--threads-steps N`` (30 with ``--acceptance``) first times the model's step at its own size in three processes
taking turns, N steps each (the same load for all): 1 thread, every core with sleeping OpenMP threads (the node's
default), every core spinning (libgomp's default): the section ``threads_side_by_side``. Writes JSON.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from cosemdepth.bench.harness import cpu_flags, make_report, write_report

ROOT = Path(__file__).resolve().parents[1]
IMAGE, INFO, ODOM = "/camera/image_raw", "/camera/camera_info", "/odom"
RECORDED_HZ = 6.25  # SynthAir's split frames: every 4th 25 Hz frame
WARMUP_FRAMES = 30
#: The node's --max-frame-gap here: the replays run up to rate/6.25 times faster than recorded, so two processed
#: frames are that much further apart in stamps than in wall time; the default gap reset (1 s of stamps) would fire
#: on the compressed time. With this, a replay's frames form one motion chain, as predict --bag runs them.
MAX_FRAME_GAP = 30.0


def percentiles(values) -> dict:
    v = np.asarray(values, dtype=np.float64)
    if not v.size:
        return {"p50": None, "p95": None, "max": None, "n": 0}
    return {
        "p50": round(float(np.percentile(v, 50)), 1),
        "p95": round(float(np.percentile(v, 95)), 1),
        "max": round(float(v.max()), 1),
        "n": int(v.size),
    }


def ratio_percentiles(values) -> dict:
    v = np.asarray(values, dtype=np.float64)
    if not v.size:
        return {"p50": None, "p5": None, "n": 0}
    return {"p50": round(float(np.percentile(v, 50)), 3), "p5": round(float(np.percentile(v, 5)), 3), "n": int(v.size)}


class Probe:
    """This process's view of the graph: when the replay wrote each image, when the node's depth and status for it
    arrived, and the node's counters."""

    def __init__(self) -> None:
        from cosemdepth.ros2.dds import Graph
        from cosemdepth.ros2.idl import idl_type

        self.graph = Graph()
        self.readers = {
            "image": self.graph.reader(IMAGE, idl_type("sensor_msgs/msg/Image"), depth=1000),
            "depth": self.graph.reader("/cosemdepth/depth", idl_type("sensor_msgs/msg/Image"), depth=1000),
            "status": self.graph.reader(
                "/cosemdepth/depth_status", idl_type("diagnostic_msgs/msg/DiagnosticArray"), depth=1000
            ),
        }
        self.written: dict[int, int] = {}
        self.depth: dict[int, tuple[int, bytes]] = {}
        self.status: list[dict] = []
        self.lock = threading.Lock()
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    @staticmethod
    def _stamp(data: bytes) -> int:
        # the header's stamp: int32 sec, uint32 nanosec right after the 4-byte encapsulation header
        sec = int.from_bytes(data[4:8], "little", signed=True)
        return sec * 10**9 + int.from_bytes(data[8:12], "little")

    def _run(self) -> None:
        from cosemdepth.ros2.idl import decode

        while not self.stop.is_set():
            self.graph.wait(0.05)
            with self.lock:
                for s in self.readers["image"].take(256):
                    self.written[self._stamp(s.data)] = s.source_ns
                for s in self.readers["depth"].take(256):
                    self.depth[self._stamp(s.data)] = (s.received_ns, s.data)
                for s in self.readers["status"].take(256):
                    msg = decode(s.data, "diagnostic_msgs/msg/DiagnosticArray")
                    values = {kv.key: kv.value for kv in msg.status[0].values}
                    values["stamp"] = self._stamp(s.data)
                    self.status.append(values)

    def counters(self) -> dict:
        with self.lock:
            last = self.status[-1] if self.status else {}
        return {k: int(last.get(k, 0)) for k in ("frames_received", "frames_processed", "frames_dropped")}

    def settle(self, timeout: float = 300.0) -> None:
        """Until the node's depth for the newest image written arrived (the node always ends on the newest image),
        or ``timeout`` seconds."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            with self.lock:
                if self.written and max(self.written) in self.depth:
                    break
            time.sleep(0.1)
        time.sleep(0.5)

    def clear(self) -> None:
        with self.lock:
            self.written.clear()
            self.depth.clear()
            self.status.clear()

    def close(self) -> None:
        self.stop.set()
        self.thread.join(5)
        self.graph.close()


#: Every process started here (stopped at the end, whatever happened).
CHILDREN: list[subprocess.Popen] = []


def cosemdepth(args, env, log: Path) -> subprocess.Popen:
    proc = subprocess.Popen(
        [sys.executable, "-m", "cosemdepth", *map(str, args)], env=env, stdout=open(log, "w"), stderr=subprocess.STDOUT
    )
    CHILDREN.append(proc)
    return proc


def stop_children() -> None:
    for proc in CHILDREN:
        if proc.poll() is None:
            proc.terminate()
    for proc in CHILDREN:
        try:
            proc.wait(60)
        except subprocess.TimeoutExpired:
            proc.kill()


def rss_mib(pid: int) -> float | None:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None


def replay(bag: Path, rate_hz: float, env, log: Path, *extra) -> tuple[float, int]:
    """``(seconds, images published)`` of one replay."""
    t0 = time.monotonic()
    proc = cosemdepth(["replay", bag, "--rate", rate_hz / RECORDED_HZ, "--wait", 30, *extra], env, log)
    if proc.wait(3600) != 0:
        raise RuntimeError(f"replay failed: {log.read_text()[-2000:]}")
    text = log.read_text()
    return time.monotonic() - t0, int(text.split(f"{IMAGE} ")[1].split()[0].strip(",;"))


def equal_to_predict(bag, depth: dict, model_args, tmp: Path, env) -> dict:
    """predict --bag on the frames the node processed; its depth messages against the node's, byte for byte."""
    from rosbags.highlevel import AnyReader

    from cosemdepth.ros2.midair_bag import keep_images

    stamps = sorted(depth)
    sub, out = tmp / "subset", tmp / "predict"
    for old in (sub, out):
        shutil.rmtree(old, ignore_errors=True)
    keep_images(bag, sub, stamps, (IMAGE, INFO))
    cmd = ["predict", *model_args, "--bag", sub, "--image-topic", IMAGE, "--pose-topic", ODOM]
    cmd += ["--camera-info-topic", INFO, "--convention", "ned", "--out", out, "--video", "none", "--no-progress"]
    proc = cosemdepth(cmd, env, tmp / "predict.log")
    if proc.wait(3600) != 0:
        return {"ok": False, "error": (tmp / "predict.log").read_text()[-500:]}
    same = 0
    with AnyReader([out / "bag"]) as r:
        ref = [bytes(raw) for c, _, raw in r.messages() if c.topic == "/cosemdepth/depth"]
    for s, raw in zip(stamps, ref):
        data = depth[s][1]
        same += data[: len(raw)] == raw and set(data[len(raw) :]) <= {0}
    (tmp / "node_depth.json").write_text(json.dumps({str(s): depth[s][1].hex() for s in stamps}))
    return {"ok": same == len(stamps) == len(ref), "frames": len(stamps), "byte_equal": same}


def run_config(a, bag, size, mode, threads, env, tmp: Path, probe: Probe, memory_minutes: float) -> dict:
    model_args = ["--model", a.model] + ([] if threads is None else ["--threads", threads])
    if size != "own":
        model_args += ["--size", size]
    if mode.startswith("fast-"):
        model_args += ["--precision", mode.split("-")[1]]
    else:
        onnx = tmp / f"int8_{size}.onnx"
        if not onnx.exists():
            s = a.own_size if size == "own" else int(size)
            cmd = ["export", "--model", a.model, "--onnx", onnx, "--size", s, s, "--int8"]
            cmd += ["--calibration-root", a.flight, "--calibration-dataset", "synthair"]
            cmd += ["--calibration-split-dir", Path(a.flight) / "splits", "--calibration-split", "test"]
            proc = cosemdepth(cmd, env, tmp / "export.log")
            if proc.wait(3600) != 0:
                return {"run": False, "reason": "export failed: " + (tmp / "export.log").read_text()[-500:]}
        model_args += ["--backend", "onnxruntime", "--onnx", onnx]
    node_log = tmp / f"node_{size}_{mode}.log"
    cmd = ["node", *model_args, "--image-topic", IMAGE, "--pose-topic", ODOM, "--camera-info-topic", INFO]
    cmd += ["--convention", "ned", "--report-every", 60, "--summary", tmp / "summary.json"]
    cmd += ["--max-frame-gap", MAX_FRAME_GAP]
    node = cosemdepth(cmd, env, node_log)
    out: dict = {"run": True, "node_args": [str(x) for x in model_args], "rates": {}}
    try:
        probe.clear()
        replay(bag, max(a.rates), env, tmp / "warmup.log", "--duration", WARMUP_FRAMES / RECORDED_HZ)
        probe.settle()
        for rate in a.rates:
            base = probe.counters()
            probe.clear()
            seconds, published = replay(bag, rate, env, tmp / f"replay_{rate}.log")
            probe.settle()
            with probe.lock:
                status = list(probe.status)
                depth = dict(probe.depth)
                written = dict(probe.written)
            last = probe.counters()
            delta = {k: last[k] - base[k] for k in last}
            latency = {s: (depth[s][0] - written[s]) / 1e6 for s in depth if s in written}
            by_stamp = {v["stamp"]: v for v in status}
            step = {s: float(by_stamp[s]["step_ms"]) for s in latency if s in by_stamp}
            entry = {
                "input_hz": rate,
                "images_published": published,
                "images_received": delta["frames_received"],
                "frames_processed": delta["frames_processed"],
                "frames_dropped": delta["frames_dropped"],
                "images_lost_before_the_node": published - delta["frames_received"],
                "replay_seconds": round(seconds, 2),
                "processed_hz": round(delta["frames_processed"] / (published / rate), 2),
                "latency_ms": percentiles(list(latency.values())),
                "node_latency_ms": percentiles([float(s["latency_ms"]) for s in status]),
                "model_step_ms": percentiles([float(s["step_ms"]) for s in status]),
                "queue_ms": percentiles([float(s["queue_ms"]) for s in status]),
                "convert_ms": percentiles([float(s["convert_ms"]) for s in status]),
                # the node's own time per frame: image written -> outputs handed to DDS, less the step and the wait
                "node_overhead_ms": percentiles(
                    [float(s["latency_ms"]) - float(s["step_ms"]) - float(s["queue_ms"]) for s in status]
                ),
                # per frame, the model's step over the end-to-end latency (replay's write -> this subscriber's take)
                "step_over_latency": ratio_percentiles([step[s] / latency[s] for s in step]),
                "step_over_node_latency": ratio_percentiles(
                    [float(s["step_ms"]) / float(s["latency_ms"]) for s in status]
                ),
            }
            if rate == max(a.rates):
                entry["equal_to_predict_bag"] = equal_to_predict(bag, depth, model_args, tmp, env)
            out["rates"][str(rate)] = entry
            print(f"  {size} {mode} {rate:g} Hz: {json.dumps(entry)}", flush=True)
        top = out["rates"][str(max(a.rates))]
        out["sustained_hz"] = top["processed_hz"]
        clean = [r for r in a.rates if out["rates"][str(r)]["frames_dropped"] == 0]
        out["max_rate_without_drops_hz"] = max(clean) if clean else None
        if memory_minutes > 0:
            out["memory"] = memory_run(a, bag, node.pid, env, tmp, memory_minutes)
    finally:
        node.terminate()
        try:
            node.wait(60)
        except subprocess.TimeoutExpired:
            node.kill()
    summary = json.loads((tmp / "summary.json").read_text()) if (tmp / "summary.json").exists() else {}
    out["node_summary"] = {k: summary.get(k) for k in ("frames_received", "frames_processed", "frames_dropped",
                                                       "peak_memory_mib", "resets")}  # fmt: skip
    return out


def memory_run(a, bag, pid: int, env, tmp: Path, minutes: float) -> dict:
    rate = max(a.rates)
    proc = cosemdepth(["replay", bag, "--rate", rate / RECORDED_HZ, "--loop", "--wait", 30], env, tmp / "loop.log")
    samples, t0 = [], time.monotonic()
    try:
        while time.monotonic() - t0 < minutes * 60:
            time.sleep(5)
            samples.append((round(time.monotonic() - t0, 1), rss_mib(pid)))
    finally:
        proc.terminate()
        proc.wait(60)
    after = [m for t, m in samples if t >= 60 and m is not None]
    growth = (max(after) - after[0]) if after else None
    return {
        "minutes": minutes,
        "input_hz": rate,
        "rss_mib_after_1_min": after[0] if after else None,
        "rss_mib_end": after[-1] if after else None,
        "rss_mib_max": max(after) if after else None,
        "growth_mib": None if growth is None else round(growth, 1),
        "flat": None if growth is None else growth <= a.tolerance_mb,
        "samples": samples,
    }


#: One model-step worker of :func:`threads_side_by_side` (argv: model, threads, size; a step per line on stdin).
STEP_WORKER = r"""
import json, resource, sys, time
import torch
from cosemdepth.inference.policy import EVERY_FRAME, Streamer
from cosemdepth.jobs.model import ModelOptions, load_for
torch.set_num_threads(int(sys.argv[2]))
size = int(sys.argv[3])
model, _ = load_for(ModelOptions(sys.argv[1]))
streamer, state, i = Streamer(model, EVERY_FRAME), None, 0
k = torch.tensor([[size / 2.0] * 4])
def cpu():
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime
print("ready", flush=True)
for _ in sys.stdin:
    x = torch.rand(1, 3, size, size)
    c0, t0 = cpu(), time.perf_counter()
    with torch.inference_mode():
        out, state = streamer.step(x, torch.tensor([[1.0, 0, 0, 0]]), torch.tensor([[0.0, 0, 0.5]]), k,
                                   torch.tensor([i == 0]), state)
    print(json.dumps([time.perf_counter() - t0, cpu() - c0]), flush=True)
    i += 1
"""


def threads_side_by_side(model: str, size: int, steps: int, env: dict) -> dict:
    """The model's streaming step (fast fp32, ``size`` px, random frames) in three processes that take turns, one
    step each, so that the machine's load is the same for all: 1 thread; every core with OpenMP threads that sleep
    while they wait (the node's default, ``OMP_WAIT_POLICY=PASSIVE``); every core with libgomp's default spinning.
    Wall and process CPU ms per step (p50, p90), after 3 warm-up steps each."""
    cores = os.cpu_count() or 1
    configs = {
        "threads_1": (1, "PASSIVE"),
        f"threads_{cores}_passive": (cores, "PASSIVE"),
        f"threads_{cores}_spinning": (cores, None),
    }
    procs = {}
    try:
        for name, (threads, policy) in configs.items():
            e = {k: v for k, v in env.items() if k not in ("OMP_WAIT_POLICY", "OMP_NUM_THREADS")}
            if policy:
                e["OMP_WAIT_POLICY"] = policy
            cmd = [sys.executable, "-c", STEP_WORKER, model, str(threads), str(size)]
            procs[name] = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=e)
            CHILDREN.append(procs[name])
        for p in procs.values():
            if p.stdout.readline().strip() != "ready":
                raise RuntimeError("a step worker did not start")
        got: dict[str, list] = {n: [] for n in procs}
        names = list(procs)
        for i in range(steps + 3):
            for n in names[i % len(names) :] + names[: i % len(names)]:  # each goes first in turn
                procs[n].stdin.write("step\n")
                procs[n].stdin.flush()
                wall, cpu = json.loads(procs[n].stdout.readline())
                if i >= 3:
                    got[n].append((1e3 * wall, 1e3 * cpu))
    finally:
        for p in procs.values():
            if p.stdin:
                p.stdin.close()
            p.wait(60)
    out = {}
    for n, v in got.items():
        wall, cpu = np.array([w for w, _ in v]), np.array([c for _, c in v])
        out[n] = {
            "wall_ms_p50": round(float(np.median(wall)), 1),
            "wall_ms_p90": round(float(np.percentile(wall, 90)), 1),
            "cpu_ms_p50": round(float(np.median(cpu)), 1),
        }
    base = out["threads_1"]["wall_ms_p50"]
    for n in out:
        out[n]["wall_p50_over_1_thread"] = round(out[n]["wall_ms_p50"] / base, 3)
    return {"size": size, "steps": steps, "loadavg": list(os.getloadavg()), **out}


def acceptance(result: dict) -> dict:
    """The issue's acceptance items of one configuration: no dropped frame at 10 Hz (p95 latency), drops counted at
    30 Hz with the depth equal to predict --bag's on the processed frames, memory flat (when measured)."""
    r10, r30 = result["rates"]["10.0"], result["rates"]["30.0"]
    memory = result.get("memory")
    return {
        "no_drop_at_10hz": r10["frames_dropped"] == 0 and r10["images_lost_before_the_node"] == 0,
        "latency_p95_ms_at_10hz": r10["latency_ms"]["p95"],
        "dropped_at_30hz": r30["frames_dropped"],
        "equal_to_predict_bag_at_30hz": r30["equal_to_predict_bag"]["ok"],
        "memory_flat": None if memory is None else memory["flat"],
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--model", default=str(ROOT / "weights" / "synthair-cosemdepth"))
    p.add_argument("--flight", required=True, help="a SynthAir root (see the module docstring)")
    p.add_argument("--frames", type=int, default=200)
    p.add_argument(
        "--acceptance",
        action="store_true",
        help="the acceptance subset: --sizes own --modes fast-fp32 --rates 10 30 --memory-minutes 2 (each of them "
        "can still be given)",
    )
    p.add_argument("--rates", nargs="+", type=float, help="input rates, Hz (default 10 20 30)")
    p.add_argument("--sizes", nargs="+", help="own and/or sizes in pixels (default own 384)")
    p.add_argument("--modes", nargs="+", help="fast-fp32, fast-bf16, onnx-int8 (default all three)")
    p.add_argument(
        "--threads",
        nargs="+",
        type=int,
        help="the node's torch / ONNX Runtime intra-op threads, one node after the other for several (default: the "
        "node's default, torch's choice: every core); predict --bag runs with the node's",
    )
    p.add_argument("--own-size", type=int, default=128, help="the model's own size (for the int8 export)")
    p.add_argument("--memory-minutes", type=float, help="default 0 (2 with --acceptance)")
    p.add_argument(
        "--threads-steps",
        type=int,
        help="the model's step at its own size with 1 thread, every core sleeping, every core spinning, taking "
        "turns, this many steps each (default 0; 30 with --acceptance)",
    )
    p.add_argument("--tolerance-mb", type=float, default=8.0)
    p.add_argument("--domain", type=int, default=200 + os.getpid() % 30)
    p.add_argument("--work-dir", help="keep the bags, logs and graphs here (default: a temporary folder)")
    p.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "live_node.json"))
    a = p.parse_args(argv)
    full = not a.acceptance
    a.rates = a.rates or ([10.0, 20.0, 30.0] if full else [10.0, 30.0])
    a.sizes = a.sizes or (["own", "384"] if full else ["own"])
    a.modes = a.modes or (["fast-fp32", "fast-bf16", "onnx-int8"] if full else ["fast-fp32"])
    a.memory_minutes = a.memory_minutes if a.memory_minutes is not None else (0.0 if full else 2.0)
    a.threads = a.threads or [None]
    a.threads_steps = a.threads_steps if a.threads_steps is not None else (0 if full else 30)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(1))  # the finally blocks stop the node and replay processes

    from cosemdepth.ros2.dds import loopback_config
    from cosemdepth.ros2.midair_bag import write_midair_bag

    os.environ["CYCLONEDDS_URI"] = loopback_config()
    os.environ["ROS_DOMAIN_ID"] = str(a.domain)
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"))
    env.pop("OMP_NUM_THREADS", None)
    flags = cpu_flags() or {}
    results: dict = {}
    with tempfile.TemporaryDirectory() if a.work_dir is None else contextlib.nullcontext(a.work_dir) as tmp_:
        tmp = Path(tmp_)
        bag = tmp / "flight"
        shutil.rmtree(bag, ignore_errors=True)
        info = write_midair_bag(a.flight, "sunny", 0, bag, frames=a.frames)
        sections = {}
        if a.threads_steps > 0:
            sections["threads_side_by_side"] = threads_side_by_side(a.model, a.own_size, a.threads_steps, env)
            print(f"  threads side by side: {json.dumps(sections['threads_side_by_side'])}", flush=True)
        probe = Probe()
        try:
            first = True
            for size in a.sizes:
                for mode in a.modes:
                    for threads in a.threads:
                        key = f"{size}/{mode}" + (f"/threads-{threads}" if len(a.threads) > 1 else "")
                        if key in results:  # a thread count given twice: its second run
                            key += f"/{sum(k.startswith(key) for k in results) + 1}"
                        if mode == "fast-bf16" and not (flags.get("avx512_bf16") or flags.get("amx_bf16")):
                            results[key] = {"run": False, "reason": "this CPU has no bf16 dot-product instructions "
                                            "(no avx512_bf16 or amx_bf16 flag): bf16 convolutions would be emulated"}  # fmt: skip
                            print(f"  {key}: not run ({results[key]['reason']})")
                            continue
                        work = tmp / key.replace("/", "_")
                        work.mkdir(exist_ok=True)  # a --work-dir of an earlier run: its exported graphs are reused
                        memory = a.memory_minutes if first else 0
                        results[key] = run_config(a, bag, size, mode, threads, env, work, probe, memory)
                        first = False
                        if {10.0, 30.0} <= set(a.rates):
                            results[key]["acceptance"] = acceptance(results[key])
        finally:
            stop_children()
            probe.close()
    params = {
        "model": a.model,
        "flight_images": info["images"],
        "image_size": "384x384 rgb8",
        "recorded_hz": RECORDED_HZ,
        "rates_hz": a.rates,
        "sizes": a.sizes,
        "modes": a.modes,
        "node_threads": [t or f"the node's default ({os.cpu_count()}: torch's choice)" for t in a.threads],
        "node_omp_wait_policy": os.environ.get("OMP_WAIT_POLICY", "PASSIVE (the node's default)"),
        "acceptance_subset": a.acceptance,
        "node_max_frame_gap_s": MAX_FRAME_GAP,
        "memory_minutes": a.memory_minutes,
        "dds": "Cyclone DDS on loopback (lo, no multicast, unicast peer 127.0.0.1)",
    }
    if a.acceptance:  # its own result file beside the full run's: live_node_acceptance.json
        params["mode"] = "acceptance"
    write_report(a.out, make_report("live_node", params, results, **sections))
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
