"""One router per resource: meshes, processes, jobs, health (and the pages when present)."""
