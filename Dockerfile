# One image for the three services of the rig; docker-compose.yml picks the command.
# It carries the contract, the service kit and the three boards, not the launcher
# (`workbench/`: ralf-hil up, bench, experiments, plots), which users run on the host.
# No secret is copied in: credentials are mounted or passed at run time (.dockerignore
# keeps secrets/ and local state out of the build context).
FROM python:3.11-slim

ENV PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1

WORKDIR /opt/ralf-hil
COPY pyproject.toml README.md ./
COPY protocol ./protocol
COPY plant_emulator ./plant_emulator
COPY controller ./controller
COPY service_kit ./service_kit
COPY dsp_service ./dsp_service
RUN pip install . && useradd --create-home ralf
USER ralf
WORKDIR /home/ralf
# The numba kernels compiled into the run user's cache (~/.cache/numba), against the
# installed packages (from the home directory, so Python imports site-packages, not
# the source tree above): a service loads them in ~0.6 s instead of compiling them at
# every start. Each service logs "ready in ... s; numba kernels: N loaded from cache,
# 0 compiled" (service_kit/readiness.py).
RUN python -c "from dsp_service.kernel import warm_up as dsp; from plant_emulator.model.period_kernel import warm_up as plant; from controller.fast_tick import warm_up as ctrl; from dsp_service.arx_kernel import warm_up as arx; dsp(); plant(); ctrl(); arx()"

# Services are configured only through RALF_* environment variables.
CMD ["ralf-controller", "--help"]
