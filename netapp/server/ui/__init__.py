"""The netapp's own web pages: `/ui` lists the robots connected now, `/ui/robot/{id}` shows one robot's latest
frame with its boxes and a latency chart, live. Everything is served by the netapp (no CDN): it works offline."""
