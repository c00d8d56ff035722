"""What a person reads and sees: text with units, figures and animations of runs, sweeps and campaigns."""
