"""Camera set-up tools: intrinsics from a chessboard/ChArUco board (`intrinsics`), the rolling
shutter's row time and the exposure from LED stripes (`rows`), and a verdict on whether a camera
and its settings can receive (`check`)."""
