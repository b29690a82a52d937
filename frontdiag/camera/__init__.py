"""The camera frontend: bucketed ORB, ratio + mutual matching, E/H against a keyframe,
photometric checks. ``frontend.CameraFrontend`` is the entry point; see docs/camera.md.

Nothing is imported here so that importing the package stays free of OpenCV."""
