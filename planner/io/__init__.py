"""Reading models: file formats (``readers``), IFC through IfcOpenShell (``ifc``), and the
up axis a model is levelled by when it is read (``orientation``)."""
