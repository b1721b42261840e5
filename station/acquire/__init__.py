"""Live acquisition: the recorder, the technician (operator) and the live view."""
