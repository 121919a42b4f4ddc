"""The processing path shared by live and replay: decode -> assembly -> fusion -> results."""
