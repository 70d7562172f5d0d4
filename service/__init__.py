"""The HTTP service around :mod:`planner`: mesh uploads, a job queue, worker processes.

Build the app with :func:`service.main.create_app`; nothing is created at import time.
"""
