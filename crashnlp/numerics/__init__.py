"""CasADi machinery with no crash model in it: the NLP assembler, structure-exploiting
derivatives, Runge-Kutta steps, functions compiled to C and the compile processes."""
