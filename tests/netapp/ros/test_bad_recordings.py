"""Bad recordings: no image topic, a topic that is not an image, an unknown encoding, a truncated or corrupt bag, an
oversized message, the `ros` extra missing: one line, or the message skipped and counted; nothing hangs."""

from __future__ import annotations

import shutil
import sys

import numpy as np
import pytest

pytest.importorskip("rosbags")

from netapp.cli import main as netapp_main  # noqa: E402
from netapp.client.sources import SourceError  # noqa: E402
from netapp.ros.bags import BagSource  # noqa: E402
from netapp.ros.images import MAX_PIXELS, ImageRefused, raw_to_bgr  # noqa: E402
from tests.support.bags import grey_frames, write_bag  # noqa: E402


def stream_error(capsys, url: str, *argv: str) -> str:
    """The one error line `netapp stream` prints for a bad recording (exit 1; besides it only status lines)."""
    code = netapp_main(["stream", url, "--transport", "http", "--rate", "0", *argv])
    err = capsys.readouterr().err.strip()
    assert code == 1
    errors = [line for line in err.splitlines() if not line.startswith(("connected:", "["))]
    assert len(errors) == 1, err
    return errors[0]


def test_a_bag_with_no_image_topic_is_one_line_naming_its_topics(tmp_path, capsys, tiny_server):
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    bag = tmp_path / "chatter"
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connection = writer.add_connection("/chatter", "std_msgs/msg/String", typestore=store)
        text = store.types["std_msgs/msg/String"](data="hello")
        writer.write(connection, 1, store.serialize_cdr(text, "std_msgs/msg/String"))
    line = stream_error(capsys, tiny_server.url, "--source", str(bag))
    assert line == f"error: {bag} has no image topic (its topics: /chatter)"


def test_a_topic_that_is_no_image_topic_gets_the_image_topics(tmp_path, capsys, tiny_server):
    bag = tmp_path / "run"
    write_bag(bag, grey_frames(2), "sqlite3", topic="/front/image", other_topics=("/chatter",))
    line = stream_error(capsys, tiny_server.url, "--source", str(bag), "--topic", "/chatter")
    assert line == f"error: /chatter is not an image topic of {bag}; its image topics: /front/image"


def test_without_topic_the_first_image_topic_plays(tmp_path):
    bag = tmp_path / "run"
    write_bag(bag, grey_frames(2), "mcap", topic="/front/image", other_topics=("/chatter",))
    source = BagSource(str(bag))
    assert source.topic == "/front/image" and len(list(source)) == 2


def test_an_unknown_encoding_is_skipped_and_counted_by_its_name(tmp_path, capsys, tiny_server):
    bag = tmp_path / "run"
    write_bag(bag, grey_frames(3), "mcap", encoding="yuv422")
    source = BagSource(str(bag), rate=0)
    with pytest.raises(SourceError, match=r"no frame of /camera/image in .* could be played: image encoding 'yuv4"):
        list(source)
    (reason,) = source.skipped
    assert (
        reason.startswith("image encoding 'yuv422' is not supported (supported: rgb8, bgr8")
        and source.skipped[reason] == 3
    )
    line = stream_error(capsys, tiny_server.url, "--source", str(bag))
    assert "image encoding 'yuv422' is not supported" in line and line.endswith("(x3)")


def test_skipped_messages_are_counted_in_the_summary(tmp_path, capsys, tiny_server):
    bag = tmp_path / "run.bag"
    write_bag(bag, grey_frames(3), "ros1")
    code = netapp_main(["stream", tiny_server.url, "--source", str(bag), "--rate", "0", "--transport", "http"])
    assert code == 0
    assert "recording       /camera/image: 3 frames\n" in capsys.readouterr().out


def test_an_oversized_message_is_skipped_before_decoding(tmp_path):
    bag = tmp_path / "run.bag"
    write_bag(bag, grey_frames(3, 64, 64) + grey_frames(2, 16, 16), "ros1")
    source = BagSource(str(bag), rate=0, max_message_bytes=5_000)  # 64x64x3 is over, 16x16x3 under
    assert [f.bgr().shape for f in source] == [(16, 16, 3)] * 2
    assert source.skipped == {"oversized": 3}


def test_an_image_claiming_more_pixels_than_its_data_is_refused():
    with pytest.raises(ImageRefused, match="at most"):
        raw_to_bgr("rgb8", 100_000, 100_000, 300_000, False, np.zeros(10, np.uint8))
    assert 100_000 * 100_000 > MAX_PIXELS
    with pytest.raises(ImageRefused, match="shorter than 4 rows of 12 bytes"):
        raw_to_bgr("rgb8", 4, 4, 12, False, np.zeros(40, np.uint8))


@pytest.mark.parametrize("storage", ["mcap", "ros1"])
def test_a_truncated_bag_plays_what_it_holds_or_is_one_line(tmp_path, capsys, tiny_server, storage):
    bag = tmp_path / ("run.bag" if storage == "ros1" else "run")
    write_bag(bag, grey_frames(20), storage)
    data = bag if storage == "ros1" else next(bag.glob("*.mcap"))
    cut = tmp_path / ("cut.bag" if storage == "ros1" else "cut.mcap")
    cut.write_bytes(data.read_bytes()[: data.stat().st_size * 2 // 3])
    code = netapp_main(["stream", tiny_server.url, "--source", str(cut), "--rate", "0", "--transport", "http"])
    out = capsys.readouterr()
    if code == 1 and out.err:  # the reader refuses it at once (an index or footer missing)
        assert out.err.startswith(f"error: cannot read the recording {cut}: ") and len(out.err.splitlines()) == 1
    else:  # or plays the frames it holds and counts how it ended
        assert "truncated or corrupt recording" in out.out


@pytest.mark.parametrize("name", ["noise.mcap", "noise.bag", "noise/noise.db3"])
def test_a_corrupt_recording_is_one_line(tmp_path, capsys, tiny_server, name):
    path = tmp_path / name
    path.parent.mkdir(exist_ok=True)
    path.write_bytes(np.random.default_rng(1).bytes(4096))
    if name.endswith(".db3"):  # a bag folder whose database is noise
        bag = tmp_path / "real"
        write_bag(bag, grey_frames(1), "sqlite3")
        shutil.copy(bag / "metadata.yaml", path.parent / "metadata.yaml")
        (path.parent / "real.db3").write_bytes(path.read_bytes())
        path = path.parent
    line = stream_error(capsys, tiny_server.url, "--source", str(path))
    assert line.startswith(f"error: cannot read the recording {path}: ")


def test_without_the_ros_extra_a_recording_is_one_line_naming_it(tmp_path, capsys, tiny_server, monkeypatch):
    bag = tmp_path / "run"
    write_bag(bag, grey_frames(1), "mcap")
    monkeypatch.setitem(sys.modules, "rosbags.highlevel", None)  # importing it raises ImportError
    line = stream_error(capsys, tiny_server.url, "--source", str(bag))
    assert line == f"error: reading the recording {bag} needs the rosbags package: pip install 'netapp-toolkit[ros]'"
    monkeypatch.setitem(sys.modules, "mcap.writer", None)
    with pytest.raises(SourceError):
        BagSource(str(bag))


def test_without_the_ros_extra_mcap_output_is_one_line(tmp_path, capsys, tiny_server, monkeypatch):
    monkeypatch.setitem(sys.modules, "mcap.writer", None)
    image = tmp_path / "grey.png"
    import cv2

    cv2.imwrite(str(image), grey_frames(1)[0])
    line = stream_error(capsys, tiny_server.url, "--source", str(image), "--mcap", str(tmp_path / "out.mcap"))
    assert line == "error: --mcap needs the mcap package: pip install 'netapp-toolkit[ros]'"
