"""The Foxglove layout (foxglove.layouts) for rollout MCAP files (quadson_mjx.foxglove_mcap): a 3D view
following one environment's base, plots of its /rollout/step fields and the /log panel."""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence


def layout_json(legs: Sequence[str], env: int = 0) -> str:
    """A Foxglove layout (foxglove.layouts) for rollout files: the 3D view following env{env}/base,
    plots of base velocity against the command, roll/pitch, foot forces, closure residual, reward,
    and the /log panel; `legs`: the robot's leg names (Robot.legs), one plotted line per leg.
    eval/foxglove_layout.json is this text for Quadson's legs and env 0."""
    import foxglove.layouts as fl

    def series(path: str, label: str) -> fl.PlotSeries:
        return fl.PlotSeries(value=f"/rollout/step{{env=={env}}}.{path}", label=label)

    def plot(title: str, items) -> fl.SplitItem:
        return fl.SplitItem(
            content=fl.PlotPanel(
                title=title,
                config=fl.PlotConfig(paths=[series(p, lbl) for p, lbl in items], show_legend=True),
            )
        )

    three_d = fl.ThreeDeePanel(
        title="robot",
        config=fl.ThreeDeeConfig(
            follow_tf=f"env{env}/base",
            fixed_frame="world",
            follow_mode="follow-position",
            camera_state=fl.ThreeDeeCameraState(distance=1.2, phi=60.0, theta_offset=45.0, perspective=True),
        ),
    )
    plots = fl.SplitContainer(
        direction="column",
        items=[
            plot(
                "base velocity [m/s, rad/s]",
                [
                    ("base.vx", "vx"),
                    ("command.vx", "command vx"),
                    ("base.wz", "yaw rate"),
                    ("command.yaw_rate", "command yaw rate"),
                ],
            ),
            plot("orientation [rad]", [("base.roll", "roll"), ("base.pitch", "pitch")]),
            plot("foot normal force [N]", [(f"foot_force_n.{leg}", leg) for leg in legs]),
            plot("closure residual [m]", [(f"closure_residual_m.{leg}", leg) for leg in legs]),
            plot("reward", [("reward.total", "total")]),
        ],
    )
    left = fl.SplitContainer(
        direction="column",
        items=[
            fl.SplitItem(proportion=3, content=three_d),
            fl.SplitItem(proportion=1, content=fl.LogPanel(title="falls and resets")),
        ],
    )
    layout = fl.Layout(
        content=fl.SplitContainer(
            direction="row",
            items=[fl.SplitItem(proportion=3, content=left), fl.SplitItem(proportion=2, content=plots)],
        )
    )
    return json.dumps(json.loads(layout.to_json()), indent=2) + "\n"


if __name__ == "__main__":  # python -m quadson_mjx.foxglove_layout [ROBOT] > eval/foxglove_layout.json
    from quadson_mjx.robots import get_robot

    print(layout_json(get_robot(sys.argv[1] if len(sys.argv) > 1 else "quadson").legs), end="")
