"""The `frames` transport: binary frames on one plain WebSocket per robot (`netapp.framing`, docs/protocol.md)."""
