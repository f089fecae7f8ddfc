"""The private broker of the demo: ``secure=True`` runs the shipped config/mosquitto files (TLS,
passwords, the acl templated for the demo's prefix and device), with a real mosquitto."""

from __future__ import annotations

import threading

import paho.mqtt.client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from edgedsm.localbroker import LocalBroker


def _connect(broker: LocalBroker, user: str | None) -> tuple[mqtt.Client, object]:
    client = mqtt.Client(CallbackAPIVersion.VERSION2)
    assert broker.ca_file is not None
    client.tls_set(ca_certs=str(broker.ca_file))
    if user is not None:
        client.username_pw_set(user, broker.passwords[user])
    answered, reasons = threading.Event(), []
    client.on_connect = lambda c, u, f, reason, p: (reasons.append(reason), answered.set())
    client.connect("localhost", broker.port)
    client.loop_start()
    assert answered.wait(10)
    return client, reasons[0]


def test_the_demo_broker_uses_tls_passwords_and_the_shipped_acl():
    with LocalBroker(secure=True, prefix="plant/edgedsm", device="demo") as broker:
        assert set(broker.passwords) == {"edgedsm-demo", "edgedsm-dashboard", "edgedsm-operator", "edgedsm-viewer"}
        acl = (broker.ca_file.parent / "acl").read_text().splitlines()
        assert [line for line in acl if line.startswith(("user", "topic"))][:3] == [
            "user edgedsm-demo", "topic write plant/edgedsm/demo/#", "topic read plant/edgedsm/demo/cmd/+"]
        anonymous, reason = _connect(broker, None)
        anonymous.loop_stop()
        assert reason.is_failure
        viewer, reason = _connect(broker, "edgedsm-viewer")
        operator, reason2 = _connect(broker, "edgedsm-operator")
        try:
            assert not reason.is_failure and not reason2.is_failure
            got, subscribed = [], threading.Event()
            viewer.on_message = lambda c, u, message: got.append((message.topic, message.payload))
            viewer.on_subscribe = lambda *args: subscribed.set()
            viewer.subscribe("plant/edgedsm/#", qos=1)
            assert subscribed.wait(10)
            viewer.publish("plant/edgedsm/demo/cmd/laser", b"viewer", qos=1).wait_for_publish(5)   # denied
            operator.publish("plant/edgedsm/demo/cmd/laser", b"operator", qos=1).wait_for_publish(5)
            operator.publish("plant/edgedsm/demo/state", b"operator", qos=1).wait_for_publish(5)  # denied
            threading.Event().wait(0.5)
            assert got == [("plant/edgedsm/demo/cmd/laser", b"operator")]
        finally:
            for client in (viewer, operator):
                client.disconnect()
                client.loop_stop()
