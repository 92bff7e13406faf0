"""Datasets: Mid-Air, SynthAir (procedural, Mid-Air format), TopAir, Aeroscapes and your own flights."""
