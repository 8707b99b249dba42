"""Received bytes -> images: JPEG, H.264 (with its bitstream checks), and the pixel limits both obey."""
