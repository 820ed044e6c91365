"""Live on a robot: a ROS 2 node over DDS (no ROS installation), software in the loop, and a
MAVLink offboard bridge.

* :mod:`subterra.live.dds`: ROS 2 topics over Eclipse Cyclone DDS (extra ``subterra[ros]``).
* :mod:`subterra.live.node`: ``subterra node ground|drone``, the live node.
* :mod:`subterra.live.sil`: ``subterra sil``, the simulator and the node as two processes.
* :mod:`subterra.live.config`: the node's settings (``configs/node.toml``).

docs/live.md says how to run it next to a ROS 2 robot, and what was and was not tested.
"""

from __future__ import annotations

from subterra.live.config import NodeConfig

__all__ = ["NodeConfig"]
