"""RTP (RFC 3550) and H.264 over RTP (RFC 6184), shared by the netapp and the robot client: pure, bounded, no I/O."""
