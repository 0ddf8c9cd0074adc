# One image for the three services of the rig; docker-compose.yml picks the command.
# It carries the contract, the service kit and the three boards, not the launcher
# (`workbench/`: ralf-hil up, bench, experiments, plots), which users run on the host.
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
RUN pip install ".[fast]" && useradd --create-home ralf \
    && python -c "from dsp_service.kernel import warm_up as dsp; from plant_emulator.model.compiled import warm_up as plant; from controller.fast_tick import warm_up as ctrl; dsp(); plant(); ctrl()"
USER ralf
WORKDIR /home/ralf

# Services are configured only through RALF_* environment variables.
CMD ["ralf-controller", "--help"]
