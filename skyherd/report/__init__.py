"""A run folder → its tables, figures, summary.md and report.html (layer 4, beside scripts; it
never imports scripts). matplotlib is imported inside the plotting functions only: a command
imports its report without paying for it (`skyherd fly` plots after its verdict)."""
