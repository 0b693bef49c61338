"""Live policies a session can follow (being gathered here from session/ and learn/)."""
