"""Answer sources: the NAO's head buttons, a keyboard or buzzer box, and the simulated participant."""
