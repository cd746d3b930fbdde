"""walkaround executive: mission model, loading, compiler, runtime and command line.

``executive.core`` is the shared vocabulary (mission model, frames, problems, XML
loading) that every other package may import; it imports nothing above it.
"""

__version__ = "0.1.0"
