"""Controllers that close the loop around the plant: the paper's PID baseline, OCP and NMPC."""
