"""Socket.IO (5G-ERA): the handlers of /data and /control over the dataplane, and the bounds on its packets."""
