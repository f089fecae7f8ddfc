"""Sparkplug B 3.0 edge node: the daemon's states, statistics and alerts as Sparkplug metrics.

``SparkplugSettings`` is the ``[sparkplug]`` config table; the sink is
``edgedsm.publish.sparkplug.node.SparkplugSink`` (imported from there, so that reading a config
does not load protobuf). Topics, metrics and the rules tested: docs/sparkplug.md.
"""

from __future__ import annotations

from edgedsm.publish.sparkplug.settings import SparkplugSettings

__all__ = ["SparkplugSettings"]
