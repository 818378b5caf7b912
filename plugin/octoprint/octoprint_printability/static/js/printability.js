/*
 * printability's OctoPrint plugin: the settings page (each value checked by printability's own
 * parser as it is typed, the nozzle drawn), the "Rotary nozzle" tab (jobs with their progress,
 * the rotary-axis check, rewrite and report on request) and the notifications the server sends
 * as plugin messages.
 */
$(function () {
    "use strict";

    var PLUGIN = "printability";

    function PrintabilityViewModel(parameters) {
        var self = this;
        self.settingsViewModel = parameters[0];
        self.loginState = parameters[1];

        self.machines = ko.observableArray([]);
        self.nozzleError = ko.observable("");
        self.machineError = ko.observable("");
        self.nozzleFacts = ko.observable(null);
        self.checkedNozzle = ko.observable("");
        self.jobs = ko.observableArray([]);
        self.files = ko.observableArray([]);
        self.selectedFile = ko.observable();
        self.axis = ko.observable({state: "unknown", message: null});
        self.current = ko.observable({nozzle: "", machine: ""});

        function pluginUrl(path) {
            return BASEURL + "plugin/" + PLUGIN + "/" + path;
        }

        self.summaryUrl = function (path) {
            return pluginUrl("summary?path=" + encodeURIComponent(path || ""));
        };

        self.reportUrl = function (report) {
            return report ? BASEURL + report : "";
        };

        self.previewUrl = ko.pureComputed(function () {
            var spec = self.checkedNozzle();
            return spec && !self.nozzleError() ? pluginUrl("nozzle.svg?spec=" + encodeURIComponent(spec)) : "";
        });

        self.tabPreviewUrl = ko.pureComputed(function () {
            var spec = self.current().nozzle;
            return spec ? pluginUrl("nozzle.svg?spec=" + encodeURIComponent(spec)) : "";
        });

        self.currentNozzle = ko.pureComputed(function () {
            return self.current().nozzle;
        });

        self.currentMachine = ko.pureComputed(function () {
            return self.current().machine;
        });

        self.nozzleFactsText = ko.pureComputed(function () {
            var f = self.nozzleFacts();
            if (!f) {
                return "";
            }
            return f.kind + ", " + f.orifices + (f.orifices === 1 ? " orifice" : " orifices") +
                ", " + f.area.toFixed(3) + " mm², " + f.min_width.toFixed(3) + "–" +
                f.max_width.toFixed(3) + " mm wide" + (f.turns ? ", turns on the rotary axis" : ", round: never turns");
        });

        self.axisMissing = ko.pureComputed(function () {
            return self.axis().state === "missing";
        });

        self.axisText = ko.pureComputed(function () {
            var a = self.axis();
            if (a.state === "ok") {
                return a.letter ? "The printer reports the rotary axis " + a.letter + "." :
                    "The machine profile turns no nozzle: nothing to check.";
            }
            if (a.state === "missing") {
                return a.message;
            }
            if (a.state === "checking") {
                return "Asking the printer for its axes (M115, M114)…";
            }
            return "Not connected: the rotary axis is checked when OctoPrint connects.";
        });

        // ---------------------------------------------------------------- settings page
        var pending = {};

        function check(key, value) {
            if (pending[key]) {
                clearTimeout(pending[key]);
            }
            pending[key] = setTimeout(function () {
                var data = {};
                data[key] = value;
                OctoPrint.simpleApiCommand(PLUGIN, "check", data).done(function (r) {
                    var error = (r.errors && r.errors[key]) || "";
                    if (key === "nozzle") {
                        self.nozzleError(error);
                        self.checkedNozzle(error ? "" : (r.values.nozzle || ""));
                        self.nozzleFacts(error ? null : (r.nozzle || null));
                    } else if (key === "machine") {
                        self.machineError(error);
                    }
                });
            }, 300);
        }

        self.onBeforeBinding = function () {
            var s = self.settingsViewModel.settings.plugins.printability;
            s.nozzle.subscribe(function (v) {
                check("nozzle", v);
            });
            s.machine.subscribe(function (v) {
                check("machine", v);
            });
        };

        self.onSettingsShown = function () {
            var s = self.settingsViewModel.settings.plugins.printability;
            check("nozzle", s.nozzle());
            check("machine", s.machine());
        };

        self.onSettingsBeforeSave = function () {
            // a refused value is not sent: the server would keep the old one and say why
            var s = self.settingsViewModel.settings.plugins.printability;
            if (self.nozzleError()) {
                new PNotify({title: "printability: nozzle not saved", text: self.nozzleError(), type: "error", hide: false});
                s.nozzle(self.current().nozzle);
            }
            if (self.machineError()) {
                new PNotify({title: "printability: machine not saved", text: self.machineError(), type: "error", hide: false});
                s.machine(self.current().machine);
            }
        };

        self.onSettingsHidden = function () {
            self.refresh();
        };

        // ---------------------------------------------------------------- tab
        self.refresh = function () {
            if (!self.loginState.isUser()) {
                return;
            }
            OctoPrint.simpleApiGet(PLUGIN).done(function (r) {
                self.machines(r.machines || []);
                self.current(r.settings || {nozzle: "", machine: ""});
                self.axis(r.axis || {state: "unknown"});
                self.jobs((r.jobs || []).slice().reverse());
            });
            OctoPrint.files.listForLocation("local", true).done(function (r) {
                var names = [];
                (function walk(entries) {
                    _.each(entries || [], function (e) {
                        if (e.type === "folder") {
                            walk(e.children);
                        } else if (e.type === "machinecode") {
                            names.push(e.path);
                        }
                    });
                })(r.files || r.children);
                names.sort();
                self.files(names);
            });
        };

        function command(name) {
            var path = self.selectedFile();
            if (!path) {
                return;
            }
            OctoPrint.simpleApiCommand(PLUGIN, name, {path: path})
                .done(function () {
                    self.refresh();
                })
                .fail(function (xhr) {
                    var text = (xhr.responseJSON && xhr.responseJSON.error) || xhr.statusText;
                    new PNotify({title: "printability", text: text, type: "error", hide: false});
                });
        }

        self.rewriteSelected = function () {
            command("rewrite");
        };

        self.reportSelected = function () {
            command("report");
        };

        // ---------------------------------------------------------------- messages
        function upsertJob(m) {
            var jobs = self.jobs(), found = false;
            for (var i = 0; i < jobs.length; i++) {
                if (jobs[i].id === m.job) {
                    jobs[i] = _.extend({}, jobs[i], m, {id: m.job});
                    found = true;
                    break;
                }
            }
            if (!found) {
                jobs.unshift(_.extend({name: m.name || m.path || "", stage: "", state: "",
                                       elapsed: 0, error: null, report: null, output: null},
                                      m, {id: m.job}));
            }
            self.jobs(jobs.slice(0, 50));
        }

        self.onDataUpdaterPluginMessage = function (plugin, m) {
            if (plugin !== PLUGIN || !m) {
                return;
            }
            if (m.type === "progress") {
                upsertJob(m);
            } else if (m.type === "axis") {
                self.axis(m);
            } else if (m.type === "notify") {
                if (m.job) {
                    upsertJob({job: m.job, error: m.level === "error" ? m.text : null,
                               report: m.report || null});
                }
                new PNotify({
                    title: m.title,
                    text: _.escape(m.text) + (m.output ? ' <a href="' + _.escape(self.summaryUrl(m.output)) + '" target="_blank">summary</a>' : "") +
                        (m.report ? ' <a href="' + _.escape(self.reportUrl(m.report)) + '" target="_blank">report</a>' : ""),
                    type: m.level,
                    hide: m.level !== "error"
                });
                if (m.kind === "settings" || m.level === "success") {
                    self.refresh();
                }
            }
        };

        self.onUserLoggedIn = self.refresh;
        self.onStartupComplete = self.refresh;
        self.onEventFileAdded = self.refresh;
        self.onEventFileRemoved = self.refresh;
    }

    OCTOPRINT_VIEWMODELS.push({
        construct: PrintabilityViewModel,
        dependencies: ["settingsViewModel", "loginStateViewModel"],
        elements: ["#settings_plugin_printability", "#tab_plugin_printability"]
    });
});
