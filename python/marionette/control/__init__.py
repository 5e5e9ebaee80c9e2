"""Talking to marionette-controller: controller specs, streamed references, commands, status."""
