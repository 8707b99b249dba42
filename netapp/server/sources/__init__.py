"""Cameras the netapp pulls itself (RTSP): each one a session beside the robots' (docs/cameras.md)."""
