"""Analysis of the model: quasi-stable states, their stability, the design space and the open-loop experiments."""
