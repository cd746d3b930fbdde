"""The robot's wires: CAN drive base, SCIP lasers, NMEA GPS, camera detections (issue 14)."""
