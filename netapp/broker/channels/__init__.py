"""Frames through a broker, both ends (docs/broker.md#frames-through-a-broker): the netapp consumes a work queue and
replies to each robot's own address; the robot sends to that queue and reads its replies. One module per broker,
each importing its client library only when used (the `broker` extra)."""
