"""H.264 over RTP pushed to a session's UDP port (docs/cameras.md#rtp-push)."""
