"""Switchover that triggers itself: `decision` says when to move a robot to another placement (pure), `loop` keeps
each robot's latency reports and carries the moves out (Events, history, log)."""

from .decision import SwitchPolicy, decide
from .loop import Switchover, TooFrequent

__all__ = ["SwitchPolicy", "Switchover", "TooFrequent", "decide"]
