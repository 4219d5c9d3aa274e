"""Command lines of the workbench, each run as ``python -m workbench.cli.<name>`` from the repository root."""
