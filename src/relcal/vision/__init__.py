"""Boards, cameras, detection and rendering."""
