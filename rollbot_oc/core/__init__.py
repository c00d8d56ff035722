"""Plumbing every layer uses: errors and exit codes, checked settings, reproducible arithmetic, fast calls, files."""
