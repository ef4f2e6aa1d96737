"""Policies: scripted references for every task (learned ones live in ``sili_robots.agent``)."""

from sili_robots.policies.scripted import SCRIPTED_KINDS, scripted_policy

__all__ = ["SCRIPTED_KINDS", "scripted_policy"]
