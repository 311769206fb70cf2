"""Where the viewer listens: is an address free to listen on, and is it this machine only."""

import ipaddress
import socket

from msnerf_jax.core.errors import UserError


def check_port(host: str, port: int) -> None:
  """UserError unless host:port can be bound now (port 0: any free port)."""
  try:
    infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
  except socket.gaierror as e:
    raise UserError(f"--host {host}: cannot resolve ({e.strerror})") from None
  family, _, _, _, address = infos[0]
  with socket.socket(family, socket.SOCK_STREAM) as probe:
    try:
      probe.bind(address)
    except OSError as e:
      raise UserError(f"{host}:{port}: cannot listen there ({e.strerror}; is another "
                      "server using the port? choose one with --port)") from None


def is_loopback(host: str) -> bool:
  if host == "localhost":
    return True
  try:
    return ipaddress.ip_address(host).is_loopback
  except ValueError:
    return False
