"""Scripted test campaigns: YAML spec, runner, measurements and reports (docs/campaigns.md)."""
