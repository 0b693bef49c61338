"""The operator's side of a live session: terminal keys (``keys``) and the supervisor web console (``server``).

Both only put ``ports.Command`` objects on the session's ``ports.CommandQueue``; the session acts on
them at defined points. The console also watches the session through ``ports.SessionObserver``.
"""
