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
