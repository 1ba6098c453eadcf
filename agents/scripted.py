"""Backwards-compatible name of the scripted KinSeek baseline (now :class:`agents.seeker.KinSeeker`)."""

from agents.seeker import KinSeeker as ScriptedKinSeeker

__all__ = ["ScriptedKinSeeker"]
