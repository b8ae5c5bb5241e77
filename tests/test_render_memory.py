"""The offscreen painter of stills and videos allocates no shadow map (issue 19: the CLI's memory peak).

Shadows are off in every frame the painter draws, yet MuJoCo's context allocates a vis.quality.shadowsize^2
depth map (4096^2: 64 MB with Mesa's software renderer) unless the size is 0 when the context is made. The
picture must be the same without it.
"""

from __future__ import annotations

import mujoco
import numpy as np

from reflexarm.robots import load_robot
from reflexarm.sim import Plant
from reflexarm.sim._rendering import _Painter


def test_painter_has_no_shadow_map_and_draws_the_same_picture() -> None:
    plant = Plant(load_robot("atlas_v5_left_arm"))
    m = plant.model
    before = int(m.vis.quality.shadowsize)
    painter = _Painter(plant, 320, 240, None)
    try:
        assert painter.renderer._mjr_context.shadowSize == 0
        assert int(m.vis.quality.shadowsize) == before  # the model's own setting restored
        without = painter.render(plant.data, "t")
        # the same painter with a renderer made at the model's shadow size (the map allocated, never used)
        g = m.vis.global_
        saved = (g.offwidth, g.offheight, m.vis.quality.offsamples)
        g.offwidth, g.offheight, m.vis.quality.offsamples = max(g.offwidth, 320), max(g.offheight, 240), 0
        try:
            painter.renderer.close()
            painter.renderer = mujoco.Renderer(m, 240, 320)
        finally:
            g.offwidth, g.offheight, m.vis.quality.offsamples = saved
        assert painter.renderer._mjr_context.shadowSize == before > 0
        painter.renderer.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
        painter.renderer.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False
        with_map = painter.render(plant.data, "t")
    finally:
        painter.close()
    np.testing.assert_array_equal(without, with_map, err_msg="the still changed without the unused shadow map")
