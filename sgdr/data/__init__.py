"""Sequences: sgdr's own folder format and readers for the Spring-Gaus and PAC-NeRF layouts."""
