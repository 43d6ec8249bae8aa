"""Top-down frames of the merge road drawn with numpy (no display, no plotting library)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from envs.scenario import ScenarioGeometry

#: Frame size [px] and scales of the close-up (AV-centred) view and the whole-road strip.
WIDTH = 800
VIEW_LENGTH = 200.0  # metres shown in the close-up view
LANE_PX = 20  # close-up lane height
STRIP_LANE_PX = 6  # whole-road strip lane height
MARGIN = 10
HEIGHT = MARGIN + 4 * LANE_PX + MARGIN + 4 * STRIP_LANE_PX + MARGIN
AV_COLOR = (220, 30, 30)
ROAD_COLOR = (90, 90, 90)
RAMP_COLOR = (120, 120, 120)
BACKGROUND = (235, 235, 225)
MARKING = (250, 250, 250)


def _fill(img: np.ndarray, x0: float, x1: float, y0: int, y1: int, color: Sequence[int]) -> None:
    a, b = max(int(round(x0)), 0), min(int(round(x1)), img.shape[1])
    if b > a and y1 > y0:
        img[max(y0, 0) : min(y1, img.shape[0]), a:b] = color


def draw_frame(
    geometry: ScenarioGeometry,
    av_x: float,
    av_lane: int,
    vehicles: Sequence[tuple[float, int, tuple[int, int, int]]],
    vehicle_length: float = 5.0,
) -> np.ndarray:
    """Draw the road around the AV (top) and the whole road (bottom strip).

    Lanes are drawn as rows (lane 2 on top, the ramp / acceleration lane -1 at the bottom).

    :param geometry: road dimensions.
    :param av_x: AV road position [m] (front bumper); the close-up view is centred on it.
    :param av_lane: AV lane index g.
    :param vehicles: ``(x, lane g, RGB colour)`` of every other vehicle.
    :param vehicle_length: drawn vehicle length [m].
    :return: uint8 image of shape (HEIGHT, WIDTH, 3).
    """
    img = np.empty((HEIGHT, WIDTH, 3), dtype=np.uint8)
    img[:] = BACKGROUND
    views = (
        # (top y, lane px, metres -> px scale, left road x [m])
        (MARGIN, LANE_PX, WIDTH / VIEW_LENGTH, av_x - VIEW_LENGTH / 2),
        (MARGIN + 4 * LANE_PX + MARGIN, STRIP_LANE_PX, WIDTH / geometry.road_length, 0.0),
    )
    for top, lane_px, scale, left in views:

        def row(lane: int, top: int = top, lane_px: int = lane_px) -> int:
            return top + (2 - lane) * lane_px  # lane 2 is the top row

        def px(x: float, scale: float = scale, left: float = left) -> float:
            return (x - left) * scale

        _fill(img, px(0.0), px(geometry.road_length), row(2), row(-1), ROAD_COLOR)
        _fill(img, px(geometry.ramp_start), px(geometry.merge_end), row(-1), row(-1) + lane_px, RAMP_COLOR)
        for lane in (1, 0):  # dashed lane markings in the close-up, plain lines in the strip
            _fill(img, px(0.0), px(geometry.road_length), row(lane) - 1 if lane_px > 10 else row(lane),
                  row(lane), MARKING)
        car_h = max(int(lane_px * 0.6), 2)
        pad = (lane_px - car_h) // 2
        for x, lane, color in [*vehicles, (av_x, av_lane, AV_COLOR)]:
            x0, x1 = px(x - vehicle_length), px(x)
            if x1 - x0 < 2:
                x1 = x0 + 2
            _fill(img, x0, x1, row(lane) + pad, row(lane) + pad + car_h, color)
    return img
