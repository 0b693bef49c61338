"""A controlled study around the sessions: protocol, registry and allocation, running, progress, analysis,
power and export (``nao-trainer study``; docs/how-to/study.md)."""
