"""netapp/ros/dds_types.py: an image's data is read and written as bytes, with the very bytes (and the XTypes type
id) of the plain `sequence<uint8>` that ROS 2 peers speak."""

from __future__ import annotations

import pytest

pytest.importorskip("cyclonedds")


@pytest.mark.parametrize("data", [b"", b"\x01\x02\x03", bytes(range(256)) * 30])
def test_image_data_is_bytes_on_the_same_wire(data):
    from netapp.ros.dds_types import Header_, Image_, Time_, as_generic_reader_sees_it

    PlainImage_ = as_generic_reader_sees_it(Image_)  # noqa: N806 (a class)

    header = Header_(Time_(1, 2), "camera")
    ours = Image_(header, 1, len(data) // 3, "bgr8", 0, len(data), data)
    plain = PlainImage_(header, 1, len(data) // 3, "bgr8", 0, len(data), list(data))
    for version_2 in (False, True):
        assert ours.serialize(use_version_2=version_2) == plain.serialize(use_version_2=version_2)
    back = Image_.deserialize(plain.serialize())
    assert isinstance(back.data, bytes) and back.data == data
    assert PlainImage_.deserialize(ours.serialize()).data == list(data)
    assert Image_.__idl__.get_type_id() == PlainImage_.__idl__.get_type_id()  # peers match it as before
