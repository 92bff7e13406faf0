"""Speed of CRC32C (google-crc32c) and of reading + converting a TensorFlow checkpoint.

    PYTHONPATH=src python benchmarks/tf_checkpoint_speed.py [--checkpoint PATH] [--out result.json]

Prints a JSON object (best of ``--repeat`` runs, seconds) and writes it to ``--out`` if given. Without
``--checkpoint`` it uses ``$COSEMDEPTH_FIXTURES/tfref-s128/ckpt`` (or ``../shared/fixtures`` beside the repo) when
present.
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from pathlib import Path

import numpy as np

from cosemdepth.bench.report import print_json
from cosemdepth.io.convert import import_checkpoint
from cosemdepth.io.crc32c import crc32c
from cosemdepth.io.tf_checkpoint import CheckpointReader, is_tf_checkpoint


def best_of(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def main() -> None:
    repo = Path(__file__).resolve().parents[1]
    default = Path(os.environ.get("COSEMDEPTH_FIXTURES", repo.parent / "shared" / "fixtures")) / "tfref-s128" / "ckpt"
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--checkpoint", type=Path, default=default)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()

    result: dict = {
        "machine": {"platform": platform.platform(), "python": platform.python_version(), "numpy": np.__version__,
                    "cpus": os.cpu_count()},
        "repeat": args.repeat,
    }
    for mb in (1, 20):
        data = np.random.default_rng(0).integers(0, 256, mb * 1_000_000, dtype=np.uint8).tobytes()
        crc32c(data)  # warm-up
        s = best_of(lambda: crc32c(data), args.repeat)
        result[f"crc32c_{mb}MB_s"] = round(s, 4)
        result[f"crc32c_{mb}MB_MBps"] = round(mb / s, 1)
    if is_tf_checkpoint(args.checkpoint):
        reader = CheckpointReader(args.checkpoint)
        shard_bytes = sum(os.path.getsize(reader.shard_file(i)) for i in range(reader.num_shards))
        result["checkpoint"] = str(reader.prefix)
        result["checkpoint_data_bytes"] = shard_bytes
        read = best_of(lambda: CheckpointReader(args.checkpoint).read_all(), args.repeat)
        result["read_all_numeric_s"] = round(read, 4)
        result["read_and_convert_s"] = round(best_of(lambda: import_checkpoint(args.checkpoint), args.repeat), 4)
    print_json(result, args.out)


if __name__ == "__main__":
    main()
