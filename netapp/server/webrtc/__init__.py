"""WebRTC peers (the `webrtc` extra): `POST /webrtc/offer`, a browser's or robot's video track to the model."""
