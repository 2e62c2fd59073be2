# nginx for docker/compose.yaml: Debian bookworm's nginx (1.22, with http2 and
# grpc_pass) on the same base image as the server, so the compose set needs no image
# but debian:bookworm-slim.
FROM debian:bookworm-slim
RUN apt-get update \
 && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends nginx \
 && rm -rf /var/lib/apt/lists/* \
 && rm -f /etc/nginx/sites-enabled/default
EXPOSE 50051 8080
STOPSIGNAL SIGQUIT
CMD ["nginx", "-g", "daemon off;"]
