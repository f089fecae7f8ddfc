"""Physics-based dynamic speckle simulator (paper §2A) and its scene files."""

from edgedsm.sim.activity import region_masks, tau_c_map
from edgedsm.sim.defaults import default_scene, load_scene
from edgedsm.sim.scene import Scene, scene_from_dict
from edgedsm.sim.simulator import Simulator, simulate

__all__ = ["Scene", "Simulator", "default_scene", "load_scene", "region_masks", "scene_from_dict", "simulate",
           "tau_c_map"]
