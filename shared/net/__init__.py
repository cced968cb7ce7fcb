"""Networking: endpoints and credentials, Zenoh sessions, access control."""
