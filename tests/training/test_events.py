"""The event log: JSON lines, strict JSON (no NaN), listeners, console echo, torn last line."""

from __future__ import annotations

import json
import math

from cosemdepth.training.events import EventLog, read_events


def test_events_are_json_lines_and_a_torn_last_line_is_skipped(tmp_path, capsys):
    path = tmp_path / "events.jsonl"
    seen = []
    log = EventLog(path, console=True, listeners=[seen.append])
    log.open()
    log("checkpoint", step=3, path=tmp_path / "ck")
    log("train", step=4, loss_total=math.nan, iou=[0.5, math.inf])
    log.close()
    lines = path.read_text().splitlines()
    assert [json.loads(x)["kind"] for x in lines] == ["checkpoint", "train"]
    assert json.loads(lines[1])["loss_total"] is None and json.loads(lines[1])["iou"] == [0.5, None]
    assert [e["kind"] for e in seen] == ["checkpoint", "train"]
    err = capsys.readouterr().err
    assert "[checkpoint] step=3" in err and "[train]" not in err  # train lines only without a progress bar
    with open(path, "a") as f:
        f.write('{"kind": "train", "st')  # a crash in the middle of a write
    assert [e["kind"] for e in read_events(path)] == ["checkpoint", "train"]
    EventLog(path, console_kinds={"train"}).__call__("train", step=5)  # no file opened: console only
    assert "[train] step=5" in capsys.readouterr().err
