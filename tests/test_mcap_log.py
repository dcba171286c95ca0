"""Training-log MCAP: JSON messages read back by the mcap library, and a killed writer's file recovers."""

import json

import pytest
from mcap.reader import make_reader

from quadson_mjx import mcap_check
from quadson_mjx.mcap_log import McapLog, nest_metrics


def test_nest_metrics_groups_by_first_segment_and_nulls_nan():
    nested = nest_metrics(
        {"eval/episode_reward": 2, "eval/episode_reward/lateral_l2": float("nan"), "steps": 5}
    )
    assert nested == {"eval": {"episode_reward": 2.0, "episode_reward_lateral_l2": None}, "steps": 5.0}


def _write(path, n, close=True):
    log = McapLog(path)
    log.metadata("env_config", {"json": "{}"})
    log.attachment("model.xml", b"<mujoco/>", "application/xml")
    sizes = []
    for i in range(n):
        log.log("/train/metrics", nest_metrics({"eval/episode_reward": float(i)}), 1_000 * (i + 1))
        sizes.append(path.stat().st_size)
    if close:
        log.close()
    return sizes


def test_complete_file_reads_back_with_schema_counts_and_metadata(tmp_path):
    path = tmp_path / "train.mcap"
    _write(path, 4)
    with open(path, "rb") as f:
        reader = make_reader(f)
        msgs = list(reader.iter_messages())
        assert [json.loads(m.data)["eval"]["episode_reward"] for _, _, m in msgs] == [0.0, 1.0, 2.0, 3.0]
        schema = json.loads(msgs[0][0].data)
        assert msgs[0][0].encoding == "jsonschema" and "eval" in schema["properties"]
        assert [m.name for m in reader.iter_metadata()] == ["env_config"]
        assert [a.name for a in reader.iter_attachments()] == ["model.xml"]
    report = mcap_check.check(path)
    assert report.complete and report.counts["/train/metrics"] == 4
    assert mcap_check.main([str(path), "--expect-topic", "/train/metrics"]) == 0
    assert mcap_check.main([str(path), "--expect-topic", "/tf"]) == 2


def test_refuses_to_overwrite(tmp_path):
    path = tmp_path / "train.mcap"
    path.write_bytes(b"x")
    with pytest.raises(FileExistsError, match="refusing"):
        McapLog(path)


@pytest.mark.parametrize("fraction", [0.0, 0.3, 0.6])
def test_killed_writer_keeps_every_flushed_message(tmp_path, fraction):
    # A writer killed mid-write: the file ends 1 byte + `fraction` into the chunk of the 4th message.
    path = tmp_path / "train.mcap"
    sizes = _write(path, 4, close=False)
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: sizes[2] + 1 + int(fraction * (sizes[3] - sizes[2]))])
    report = mcap_check.check(cut)
    assert not report.complete
    assert report.counts["/train/metrics"] == 3
    assert [m["eval"]["episode_reward"] for _, _, m in mcap_check.recover_messages(cut)] == [0.0, 1.0, 2.0]
    assert mcap_check.main([str(cut)]) == 1
    fixed = tmp_path / "fixed.mcap"
    mcap_check.recover(cut, fixed)
    again = mcap_check.check(fixed)
    assert again.complete and again.counts["/train/metrics"] == 3


def _index(path):
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    return summary.chunk_indexes, summary.attachment_indexes


def _flip(path, out, offset):
    data = bytearray(path.read_bytes())
    data[offset] ^= 0x5A
    out.write_bytes(bytes(data))
    return out


def _rewards(path):
    return [m["eval"]["episode_reward"] for _, _, m in mcap_check.recover_messages(path)]


@pytest.mark.parametrize("where", ["compressed data", "length field"])
def test_damaged_chunk_is_reported_and_later_messages_are_kept_regression(tmp_path, where, capsys):
    # Regression (issue 13, item 2): a flipped byte in a compressed chunk crashed the checker with a
    # ZstdError traceback (or stopped it there, losing every later message). McapLog writes one
    # chunk per message, so exactly the second message (reward 1.0) is lost, and 0, 2, 3 remain.
    path = tmp_path / "train.mcap"
    _write(path, 4)
    chunks, _ = _index(path)
    second = sorted(chunks, key=lambda c: c.chunk_start_offset)[1]
    # a chunk record: opcode (1 byte), length (8), then its fields; its compressed bytes end it
    offset = second.chunk_start_offset + (second.chunk_length - 5 if where == "compressed data" else 6)
    bad = _flip(path, tmp_path / "bad.mcap", offset)
    report = mcap_check.check(bad)
    assert not report.complete and report.counts["/train/metrics"] == 3
    assert f"offset {second.chunk_start_offset}" in report.damaged[0] and "CHUNK" in report.damaged[0]
    assert _rewards(bad) == [0.0, 2.0, 3.0]
    assert mcap_check.main([str(bad)]) == 1
    assert "damaged: offset" in capsys.readouterr().out
    fixed = tmp_path / "fixed.mcap"
    mcap_check.recover(bad, fixed)
    again = mcap_check.check(fixed)
    assert again.complete and again.counts["/train/metrics"] == 3
    assert again.metadata == ["env_config"] and again.attachments == ["model.xml"]


def test_flipped_byte_in_an_attachment_is_not_complete_regression(tmp_path):
    # Regression (issue 13, item 2): a damaged attachment reported "complete" (its CRC was not read).
    path = tmp_path / "train.mcap"
    _write(path, 2)
    _, attachments = _index(path)
    a = attachments[0]
    bad = _flip(path, tmp_path / "bad.mcap", a.offset + a.length - 6)  # in its data, before the CRC
    report = mcap_check.check(bad)
    assert not report.complete and "CRC" in report.error and "model.xml" in report.error
    assert report.counts["/train/metrics"] == 2 and report.attachments == []
    assert mcap_check.main([str(bad)]) == 1


def test_recover_keeps_metadata_and_attachments_regression(tmp_path):
    # Regression (issue 13, item 2): --recover dropped metadata (configs, versions) and attachments.
    path = tmp_path / "train.mcap"
    sizes = _write(path, 3, close=False)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[: sizes[1] + 20])  # into the third chunk
    fixed = tmp_path / "fixed.mcap"
    assert mcap_check.main([str(cut), "--recover", str(fixed)]) == 1
    with open(fixed, "rb") as f:
        reader = make_reader(f)
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
        att = {a.name: a.data for a in reader.iter_attachments()}
    assert meta == {"env_config": {"json": "{}"}} and att == {"model.xml": b"<mujoco/>"}
    assert _rewards(fixed) == [0.0, 1.0]


def test_recover_never_overwrites_regression(tmp_path, capsys):
    # Regression (issue 13, item 2): `--recover X X` opened the output before reading the input and
    # destroyed it; any existing OUT was overwritten. Both are usage errors now (exit 2), untouched.
    path = tmp_path / "train.mcap"
    sizes = _write(path, 3, close=False)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[: sizes[1] + 20])  # into the third chunk
    before = cut.read_bytes()
    assert mcap_check.main([str(cut), "--recover", str(cut)]) == 2
    assert "is the input file" in capsys.readouterr().err
    other = tmp_path / "other.mcap"
    other.write_bytes(b"keep me")
    assert mcap_check.main([str(cut), "--recover", str(other)]) == 2
    assert "exists" in capsys.readouterr().err
    assert cut.read_bytes() == before and other.read_bytes() == b"keep me"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cut.mcap", "other.mcap", "train.mcap"]


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err
    assert len([line for line in err.splitlines() if line.strip()]) == 1, err
    assert err.startswith("error: ") and "Traceback" not in err, err
    return err


def _killed_rollout_file(path):
    """A rollout writer (foxglove's streaming MCAP writer) killed after 30 flushed messages and 5
    more: the bytes on disk at that moment, which end in the chunk header whose length the writer
    fills in only when it finishes the chunk (2^64 - 1 until then)."""
    from quadson_mjx.foxglove_mcap import RolloutWriter
    from quadson_mjx.robots import get_robot

    robot = get_robot("quadson")
    live = path.with_name("live.mcap")
    w = RolloutWriter(live, robot.load_model("flat"), 1, 0.02, robot.legs)
    w.write_metadata("rollout", {"controller": "gait"})
    for i in range(35):
        w.log(1_000 * (i + 1), "info", f"message {i}")
        if i % 10 == 9:
            w.flush()
    path.write_bytes(live.read_bytes())
    w.close()
    live.unlink()


def test_regression_killed_rollout_reports_truncation_not_a_huge_chunk(tmp_path, capsys):
    # Regression: mcap_check on a killed rollout reported "a CHUNK of 18446744073709551615 bytes cut
    # short: the file ends 18446744073709551571 bytes early" (the streaming writer's placeholder
    # length read as a length). Now: where the file ends and how many messages were kept.
    cut = tmp_path / "killed.mcap"
    _killed_rollout_file(cut)
    size = cut.stat().st_size
    report = mcap_check.check(cut)
    assert not report.complete and report.truncated_at == size and report.counts["/log"] == 30
    assert mcap_check.main([str(cut)]) == 1
    out = capsys.readouterr().out
    assert f"truncated at byte {size}: the writer was killed" in out
    assert "30 complete messages recovered" in out and "18446744073709551" not in out
    fixed = tmp_path / "fixed.mcap"
    assert mcap_check.main([str(cut), "--recover", str(fixed)]) == 1
    again = mcap_check.check(fixed)
    assert again.complete and again.counts["/log"] == 30 and again.truncated_at is None


def test_regression_mcap_check_bad_paths_are_one_line_usage_errors(tmp_path, capsys):
    # Regression: a folder as input or as --recover OUT gave a traceback; a missing input with
    # --recover wrote an empty "recovered" file. Each is one line and exit status 2, nothing written.
    good = tmp_path / "train.mcap"
    _write(good, 2)
    before = sorted(p.name for p in tmp_path.iterdir())
    cases = [
        ([str(tmp_path)], "is a folder"),
        ([str(tmp_path / "missing.mcap")], "no such file"),
        ([str(tmp_path / "missing.mcap"), "--recover", str(tmp_path / "out.mcap")], "no such file"),
        ([str(good), "--recover", str(tmp_path)], "exists"),
        ([str(good), "--recover", str(tmp_path / "no" / "out.mcap")], "does not exist"),
        ([str(good), "--recover", str(good / "out.mcap")], "is a file, not a folder"),
        ([str(good), "--no-such-flag"], "unrecognized arguments"),
    ]
    for argv, words in cases:
        assert mcap_check.main(argv) == 2, argv
        assert words in _one_line_error(capsys), argv
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_regression_mcap_check_read_only_output_folder_is_refused(tmp_path, capsys, monkeypatch):
    # A read-only folder for --recover OUT. As root every folder is writable, so os.access is
    # monkeypatched to answer as for a read-only folder (what errors.check_writable asks).
    import os

    good = tmp_path / "train.mcap"
    _write(good, 2)
    ro = tmp_path / "ro"
    ro.mkdir()
    real = os.access
    monkeypatch.setattr(os, "access", lambda p, mode: False if str(p) == str(ro) else real(p, mode))
    assert mcap_check.main([str(good), "--recover", str(ro / "out.mcap")]) == 2
    assert "not writable" in _one_line_error(capsys)
    assert list(ro.iterdir()) == []


def test_damaged_chunk_whose_header_reads_as_a_footer_loses_only_itself_regression(tmp_path):
    # Regression: after a damaged chunk the walk searched on from the chunk's second byte, and a
    # footer's body is 20 bytes that any bytes parse as. Times 0x1402 and 0x1500 make the chunk's
    # first field read as a footer of length 20 (bytes 02 14 00 00 00 00 00 00 | 00 15 ...), so
    # every later message was lost (25 of 400 rewritten test-training logs with a flipped byte).
    from mcap.writer import CompressionType, Writer

    path = tmp_path / "log.mcap"
    with open(path, "wb") as f:
        w = Writer(f, compression=CompressionType.ZSTD)
        w.start(profile="", library="test")
        sid = w.register_schema(name="s", encoding="jsonschema", data=b"{}")
        cid = w.register_channel(topic="/t", message_encoding="json", schema_id=sid)
        for times in ([0x1000], [0x1402, 0x1500], [0x2000]):
            for t in times:
                w.add_message(cid, log_time=t, publish_time=t, data=json.dumps({"t": t}).encode())
            w.flush()
        w.finish()
    chunks, _ = _index(path)
    second = sorted(chunks, key=lambda c: c.chunk_start_offset)[1]
    bad = _flip(path, tmp_path / "bad.mcap", second.chunk_start_offset + second.chunk_length - 5)
    contents = mcap_check.read_contents(bad)
    assert [m.log_time for m in contents.messages] == [0x1000, 0x2000]
    assert len(contents.damaged) == 1 and f"offset {second.chunk_start_offset}: CHUNK" in contents.damaged[0]
    assert contents.footer is not None and contents.footer.summary_start > second.chunk_start_offset
