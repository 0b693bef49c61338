"""Recorded data: the published dataset's layout, the turn-table importer and offline engagement."""
