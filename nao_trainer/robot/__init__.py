"""Robot adapters: the NAOqi client over ``qi`` and a NAO stand-in served over a real qi session."""
