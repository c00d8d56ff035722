"""Plumbing every layer uses: errors and exit codes, checked settings, reproducible arithmetic, the RK4
integrator, fast calls, files."""
