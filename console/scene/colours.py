"""The colours of the 3-D view: one each for what it draws (the panel's legend names them)."""

ROV_RGB = (232, 96, 30)          # the vehicle as last received, and its trail
GHOST_RGB = (120, 200, 255)      # the pose predicted now
TARGET_RGB = (80, 230, 120)      # a position target and its previewed path
UNCERTAINTY_RGB = (255, 80, 80)  # how far off the prediction may be
FRUSTUM_RGB = (255, 230, 120)    # the camera now, and its seabed footprint
CAPTURE_RGB = (230, 120, 255)    # the camera where the picture shown was captured
FOLLOW_RGB = (255, 210, 0)       # the ray to the followed object (the ROI's colour)
# The objects the ROV recognised, by class (docs/PROTOCOL.md §11).
OBJECT_RGB = {"amphora": (214, 140, 80), "pipe": (170, 170, 190), "timber": (150, 110, 70), "ladder": (120, 200, 200),
              "unknown": (200, 200, 120)}
