"""The model: parameters, equations of motion, rotations and the code generation of CasADi Functions."""
