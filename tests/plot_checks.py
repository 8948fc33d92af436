"""The PNGs each stage writes into its run folder (README "Pictures"; oacli/io/plots)."""

PNGS = {
    "track": ("tracking_error.png", "inputs.png", "views.png"),
    "plan": ("top_view.png", "side_view.png"),
    "smooth": ("top_view.png", "side_view.png"),
    "excite": ("information.png", "inputs.png"),
    "estimate": ("convergence.png", "innovation.png"),
}
