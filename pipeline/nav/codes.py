"""The discrete action space's codes (Habitat's): ``routes.zarr`` stores them, the planners emit them, the evaluator's
agents act with them. A leaf: constants only, so the routes store reads them without the planners."""

STOP, FORWARD, LEFT, RIGHT = 0, 1, 2, 3
ACTION_NAMES = {STOP: "stop", FORWARD: "forward", LEFT: "left", RIGHT: "right"}
