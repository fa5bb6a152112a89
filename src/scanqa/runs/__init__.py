"""The runs that use the whole pipeline: batch and campaign runs, the demo and
on-boarding."""
